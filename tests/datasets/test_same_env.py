"""`simreel.datasets.same_env`: what makes recordings one env (everything but provenance and simreel's own
version), and the message naming the first field that differs with both values."""

from __future__ import annotations

import dataclasses

import pytest
from support.mcap_samples import synthetic_meta

from simreel.datasets.same_env import PROVENANCE_FIELDS, check_same_env, env_definition, first_difference
from simreel.errors import EnvMismatchError
from simreel.model.state_tree import LeafSpec


def _versions(**changes: str) -> dict[str, str]:
    return {"simreel": "0.1.0", "mani_skill": "3.0.1", "sapien": "3.0.3", "torch": "2.13.0+cpu", **changes}


def test_provenance_fields_and_simreels_own_version_may_differ():
    a = dataclasses.replace(synthetic_meta(), versions=_versions(), created_utc="2026-01-01", command="record a")
    b = dataclasses.replace(a, created_utc="2026-02-02", command="record b", source={"format": "maniskill"},
                            provenance={"operation": "merge"}, format_version=0, versions=_versions(simreel="0.2.0"),
                            recording_id="b1")
    check_same_env([("a.h5", a), ("b.h5", b)])
    assert env_definition(a) == env_definition(b)
    assert set(PROVENANCE_FIELDS) == {"created_utc", "command", "recording_id", "source", "provenance",
                                      "format_version"}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"env_id": "Other-v0"}, "env_id is 'Other-v0' there, 'Synthetic-v0' in a.h5"),
        ({"env_kwargs": {"robot_uids": "fetch"}}, "env_kwargs.robot_uids is 'fetch' there, '<absent>' in a.h5"),
        ({"control_mode": "pd_joint_pos"}, "control_mode is 'pd_joint_pos' there, None in a.h5"),
        ({"render_backend": "gpu"}, "render_backend is 'gpu' there, 'none' in a.h5"),
        ({"num_envs": 4}, "num_envs is 4 there, 1 in a.h5"),
        ({"sim_config": {"spacing": 5}}, "sim_config.spacing is 5 there, '<absent>' in a.h5"),
        ({"versions": _versions(mani_skill="3.0.2")}, "versions.mani_skill is '3.0.2' there, '3.0.1' in a.h5"),
        ({"state_layout": {"actors/cube": LeafSpec((13,), "float64")}},
         "state_layout.actors/cube.dtype is 'float64' there, 'float32' in a.h5"),
        ({"pose_bodies": []}, "pose_bodies is [] there, ['cube', 'robot/base', 'robot/arm'] in a.h5"),
        ({"unknown": ["rewards"]}, "unknown is ['rewards'] there, [] in a.h5"),
        ({"imports": ["my_tasks.py"]}, "imports is ['my_tasks.py'] there, [] in a.h5"),
    ],
    ids=["env_id", "env_kwargs", "control_mode", "render_backend", "num_envs", "sim_config", "versions",
         "state_layout", "pose_bodies", "unknown", "imports"],
)
def test_a_difference_that_defines_the_env_is_named_with_both_values(change, message):
    a = dataclasses.replace(synthetic_meta(), versions=_versions())
    b = dataclasses.replace(a, **change)
    with pytest.raises(EnvMismatchError) as e:
        check_same_env([("a.h5", a), ("a2.h5", a), ("b.mcap", b)])
    assert str(e.value).startswith(f"b.mcap records another env than a.h5: {message}; only recordings of one env")


def test_first_difference_walks_objects_in_order_and_lists_item_by_item():
    assert first_difference({"a": 1, "b": [1, 2]}, {"a": 1, "b": [1, 2]}) is None
    assert first_difference({"a": 1, "b": [1, 2]}, {"a": 1, "b": [1, 3]}) == ("b[1]", 2, 3)
    assert first_difference({"a": [1]}, {"a": [1, 2]}) == ("a", [1], [1, 2])
    assert first_difference({"a": 1}, {"a": 1.0}) == ("a", 1, 1.0)  # JSON of another type: not the same setting
    assert first_difference({"x": 1}, {"x": 1, "y": 2}) == ("y", "<absent>", 2)


_LONG = ["versions", "sim_config", "control_freq", "contacts", "body_poses", "info", "scene_seeds", "fail"]


@pytest.mark.parametrize(
    ("first", "other", "message"),
    [
        ({"unknown": _LONG}, {"unknown": [*_LONG[:-1], "rewards", "fail"]},
         "unknown holds ['rewards'] there, not in a.h5"),
        ({"unknown": [*_LONG, "rewards"]}, {"unknown": _LONG}, "unknown holds ['rewards'] in a.h5, not there"),
        ({"unknown": [*_LONG, "rewards"]}, {"unknown": [*_LONG, "env_states", "obs"]},
         "unknown holds ['env_states', 'obs'] there, not in a.h5, and ['rewards'] in a.h5, not there"),
        ({"unknown": _LONG}, {"unknown": [*_LONG, "fail"]},
         "unknown is ...scene_seeds', 'fail', 'fail'] there, ...scene_seeds', 'fail'] in a.h5"),
        ({"env_kwargs": {"robot_uids": "panda_" + "x" * 100 + "1"}}, {"env_kwargs": {"robot_uids": "panda_" + "x" * 100 + "2"}},
         f"env_kwargs.robot_uids is ...{'x' * 20}2' there, ...{'x' * 20}1' in a.h5"),
    ],
    ids=["one-holds-more", "one-holds-less", "each-holds-another", "an-item-twice", "long-text"],
)
def test_a_long_value_is_shown_by_what_differs_never_cut_before_it(first, other, message):
    """Values too long for the line are shown where they differ: what each list holds that the other lacks, or
    both values from just before their first differing character."""
    a = dataclasses.replace(synthetic_meta(), **first)
    with pytest.raises(EnvMismatchError) as e:
        check_same_env([("a.h5", a), ("b.mcap", dataclasses.replace(a, **other))])
    assert str(e.value).startswith(f"b.mcap records another env than a.h5: {message}; only recordings of one env")
