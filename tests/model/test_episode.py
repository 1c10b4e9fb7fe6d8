"""`simreel.model`: the field table, step blocks, episodes ⇄ fields, metadata JSON, and the exact error for
every kind of malformed input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simreel.errors import EpisodeLayoutError, MetadataError, UsageError
from simreel.model.blocks import StepBlock
from simreel.model.episode import Episode
from simreel.model.fields import FieldSpec, episode_fields
from simreel.model.meta import ContactChannel, EpisodeMeta, RecordingMeta
from simreel.model.selection import EpisodeSelection
from simreel.model.state_tree import LeafSpec


def _meta(**changes) -> RecordingMeta:
    meta = RecordingMeta(
        env_id="PickCube-v1",
        action_space={"shape": [2]},
        state_layout={"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((), "float64")},
        obs_layout={"agent/qpos": LeafSpec((9,), "float32")},
        info_layout={"is_grasped": LeafSpec((), "bool")},
        contact_channels=[ContactChannel("net", ("cube",)), ContactChannel("pair", ("panda/finger", "cube"))],
        pose_bodies=["cube", "table"],
    )
    return dataclasses.replace(meta, **changes)


def _episode(T: int = 3) -> Episode:
    rng = np.random.default_rng(0)
    return Episode(
        meta=EpisodeMeta(index=4, seed=7, length=T),
        actions=rng.standard_normal((T, 2)).astype(np.float32),
        rewards=rng.standard_normal(T).astype(np.float32),
        terminated=np.zeros(T, bool), truncated=np.zeros(T, bool), success=np.ones(T, bool), fail=np.zeros(T, bool),
        env_states={"actors/cube": rng.standard_normal((T + 1, 13)).astype(np.float32), "goal": np.zeros(T + 1)},
        obs={"agent/qpos": np.zeros((T + 1, 9), np.float32)},
        info={"is_grasped": np.zeros(T, bool)},
        contact_forces=np.zeros((T, 2, 3), np.float32),
        body_poses=np.zeros((T + 1, 2, 7), np.float32),
    )


def test_the_field_table_lists_every_array_with_dtype_shape_and_rows():
    table = [(f.name, f.dtype, f.shape, f.rows) for f in episode_fields(_meta())]
    assert table == [
        ("actions", "float32", (2,), "T"),
        ("rewards", "float32", (), "T"),
        ("terminated", "bool", (), "T"),
        ("truncated", "bool", (), "T"),
        ("success", "bool", (), "T"),
        ("fail", "bool", (), "T"),
        ("info/is_grasped", "bool", (), "T"),
        ("contact_forces", "float32", (2, 3), "T"),
        ("env_states/actors/cube", "float32", (13,), "T+1"),
        ("env_states/goal", "float64", (), "T+1"),
        ("obs/agent/qpos", "float32", (9,), "T+1"),
        ("body_poses", "float32", (2, 7), "T+1"),
    ]
    bare = [f.name for f in episode_fields(_meta(contact_channels=[], pose_bodies=[], obs_layout={}))]
    assert "contact_forces" not in bare and "body_poses" not in bare and not any(n.startswith("obs/") for n in bare)
    assert FieldSpec("x", "bool", (), per_state=True).row_count(5) == 6


def test_an_episode_is_its_fields_and_its_blocks():
    ep = _episode()
    fields = ep.fields()
    assert {f.name for f in episode_fields(_meta())} == set(fields)
    again = Episode.from_fields(ep.meta, fields)
    assert all(np.array_equal(again.fields()[k], v) for k, v in fields.items())
    reset, steps = ep.reset_block(), ep.steps_block()
    assert reset.rows == 1 and set(reset.arrays) == {"env_states/actors/cube", "env_states/goal", "obs/agent/qpos",
                                                     "body_poses"}
    assert steps.rows == 3 and np.array_equal(steps["env_states/goal"], ep.env_states["goal"][1:])
    assert np.array_equal(steps["actions"], ep.actions)


def test_conform_casts_to_the_table_dtypes_without_copying_what_fits():
    ep = _episode()
    block = ep.steps_block()
    arrays = dict(block.arrays, rewards=block["rewards"].astype(np.float64))
    out = StepBlock(arrays, block.rows).conform(episode_fields(_meta()), episode=4)
    assert out["rewards"].dtype == np.float32
    assert out["actions"] is block["actions"]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: a.pop("contact_forces"), "episode 4: no contact_forces to write (the recording's layout lists it)"),
        (lambda a: a.update(actions=np.zeros((3, 5))), "episode 4: actions has shape (3, 5), expected (3, 2) from the layout"),
        (lambda a: a.update({"obs/extra": np.zeros((3, 1))}),
         "episode 4: obs/extra not in the recording's layout; describe every field in the RecordingMeta"),
    ],
    ids=["missing", "shape", "extra"],
)
def test_conform_names_the_episode_and_the_field(change, message):
    block = _episode().steps_block()
    arrays = dict(block.arrays)
    change(arrays)
    with pytest.raises(EpisodeLayoutError) as e:
        StepBlock(arrays, block.rows).conform(episode_fields(_meta()), episode=4)
    assert str(e.value).startswith(message)


def test_a_block_of_mixed_row_counts_is_refused():
    with pytest.raises(EpisodeLayoutError, match=r"a step block mixes row counts \[2, 3\]"):
        StepBlock.of({"actions": np.zeros((3, 2)), "rewards": np.zeros(2)})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda ep: dataclasses.replace(ep, rewards=ep.rewards[:-1]), "episode 4: rewards has 2 rows, expected 3"),
        (lambda ep: dataclasses.replace(ep, env_states={"goal": np.zeros(3)}),
         "episode 4: env_states/goal has 3 rows, expected 4"),
        (lambda ep: dataclasses.replace(ep, info={"x": np.zeros(4)}), "episode 4: info/x has 4 rows, expected 3"),
        (lambda ep: dataclasses.replace(ep, body_poses=np.zeros((3, 2, 7))), "episode 4: body_poses has 3 rows, expected 4"),
        (lambda ep: dataclasses.replace(ep, contact_forces=np.zeros((4, 2, 3))),
         "episode 4: contact_forces has 4 rows, expected 3"),
    ],
)
def test_row_counts_that_do_not_fit_t_or_t_plus_1_are_named(change, message):
    with pytest.raises(EpisodeLayoutError) as e:
        change(_episode()).check_shapes()
    assert str(e.value) == message


def test_from_fields_needs_actions_and_the_done_flags_and_leaves_the_others_unknown():
    fields = _episode().fields()
    del fields["rewards"], fields["fail"]
    episode = Episode.from_fields(EpisodeMeta(index=2), fields)
    assert episode.rewards is None and episode.fail is None and "rewards" not in episode.fields()
    del fields["actions"], fields["truncated"]
    with pytest.raises(EpisodeLayoutError) as e:
        Episode.from_fields(EpisodeMeta(index=2), fields)
    assert str(e.value) == "episode 2: no actions, truncated"


def test_fields_a_file_does_not_hold_leave_the_table():
    names = [f.name for f in episode_fields(_meta(unknown=["rewards", "fail", "versions"]))]
    assert "rewards" not in names and "fail" not in names and "success" in names


def test_metadata_round_trips_through_json():
    meta = _meta(sim_config={"sim_freq": 100}, control_freq=20.0)
    again = RecordingMeta.from_json(meta.to_json())
    assert again == meta
    ep = EpisodeMeta(index=3, seed=None, reset_options={"reconfigure": True}, length=9, success=False)
    assert EpisodeMeta.from_json(ep.to_json()) == ep
    assert RecordingMeta.from_json({**meta.to_json(), "a_field_of_a_newer_simreel": 1}) == meta


def test_metadata_of_files_recorded_before_the_scene_fingerprint_still_reads():
    """Recordings made before simreel kept a scene fingerprint lack these keys: they read as empty (not compared)."""
    old = {k: v for k, v in _meta().to_json().items() if k != "scene_fingerprint"}
    assert RecordingMeta.from_json(old).scene_fingerprint == {}
    ep = EpisodeMeta.from_json({"index": 1, "seed": 4, "length": 9})
    assert (ep.scene_changes, ep.verification) == ({}, None)
    fingerprinted = _meta(scene_fingerprint={"bodies": {"cube": {"mass": 0.064}}, "controllers": {}})
    assert RecordingMeta.from_json(fingerprinted.to_json()) == fingerprinted
    assert list(fingerprinted.to_json()["scene_fingerprint"]) == ["zlib+base64"]  # stored packed
    assert RecordingMeta.from_json({**fingerprinted.to_json(), "scene_fingerprint": fingerprinted.scene_fingerprint}) \
        == fingerprinted  # and read unpacked too
    ep = EpisodeMeta(index=2, scene_changes={"bodies": {"cube": {"mass": 0.08}}}, verification={"verdict": "exact"})
    assert EpisodeMeta.from_json(ep.to_json()) == ep


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ([], "recording metadata is list, expected a JSON object"),
        ({}, "recording metadata lacks 'env_id'"),
        ({"env_id": 3}, "recording metadata: env_id is 3, expected str"),
        ({"env_id": "X", "num_envs": "2"}, "recording metadata: num_envs is '2', expected int"),
        ({"env_id": "X", "num_envs": True}, "recording metadata: num_envs is True, expected int"),
        ({"env_id": "X", "num_envs": 0}, "recording metadata: num_envs is 0, expected >= 1"),
        ({"env_id": "X", "control_mode": 5}, "recording metadata: control_mode is 5, expected str | None"),
        ({"env_id": "X", "state_layout": []}, "recording metadata: state_layout is [], expected dict"),
        ({"env_id": "X", "state_layout": {"a": {"shape": [1]}}}, "leaf spec {'shape': [1]}: expected"),
        ({"env_id": "X", "contact_channels": [{"kind": "net", "bodies": ["a", "b"]}]},
         "contact channel {'kind': 'net', 'bodies': ['a', 'b']}: expected kind 'net' with 1 body name or 'pair' with 2"),
        ({"env_id": "X", "contact_channels": [{"kind": "side"}]}, "contact channel {'kind': 'side'}: expected kind"),
        ({"env_id": "X", "scene_fingerprint": {"zlib+base64": "not base64!"}},
         "recording metadata: scene_fingerprint: the packed JSON does not decode"),
        ({"env_id": "X", "action_space": {"shape": ["2"]}},
         "recording metadata: action_space shape is ['2'], expected a list of sizes"),
    ],
)
def test_malformed_recording_metadata_is_named(doc, message):
    with pytest.raises(MetadataError) as e:
        RecordingMeta.from_json(doc)
    assert str(e.value).startswith(message)


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ("3", "episode metadata is str, expected a JSON object"),
        ({"seed": 1}, "episode metadata lacks 'index'"),
        ({"index": "0"}, "episode metadata: index is '0', expected int"),
        ({"index": -1}, "episode metadata: index is -1, expected >= 0"),
        ({"index": 0, "length": -3}, "episode metadata: length is -3, expected >= 0"),
        ({"index": 0, "seed": 1.5}, "episode metadata: seed is 1.5, expected int | None"),
        ({"index": 0, "success": "yes"}, "episode metadata: success is 'yes', expected bool | None"),
        ({"index": 0, "origin": {"file": "/a.h5", "index": 2, "scene": {"file": "/a.h5", "start": -1, "position": 2}}},
         'episode metadata: origin.scene is {"file": "/a.h5", "start": -1, "position": 2}, expected {"file": <path>, '
         '"recording": <id>, "start": <index>, "position": <count>}'),
        ({"index": 0, "origin": {"file": "/a.h5", "index": 2, "scene": "a.h5#0"}},
         'episode metadata: origin.scene is "a.h5#0", expected {"file": <path>, "recording": <id>, "start": <index>, '
         '"position": <count>}'),
        ({"index": 0, "chain": {"start": 0}},
         'episode metadata: chain is {"start": 0}, expected {"start": <index>, "position": <count>}'),
        ({"index": 0, "provenance": {"scene": {"file": "/a.h5", "recording": 7, "start": 0, "position": 2}}},
         'episode metadata: provenance.scene is {"file": "/a.h5", "recording": 7, "start": 0, "position": 2}, expected '
         '{"file": <path>, "recording": <id>, "start": <index>, "position": <count>}'),
    ],
)
def test_malformed_episode_metadata_is_named(doc, message):
    with pytest.raises(MetadataError) as e:
        EpisodeMeta.from_json(doc)
    assert str(e.value) == message


# ------------------------------------------------------------------------------------------- episode selections
HUGE = 10**20
"""Past any C size: a range of it must never be built (len(), list()), only walked as far as a file's episodes go."""


@pytest.mark.parametrize(("text", "ranges"), [
    ("0,3-7", ((0, 0), (3, 7))),
    (" 1 , 2 - 4 ,,", ((1, 1), (2, 4))),
    (",", ()),
    (f"0-{HUGE}", ((0, HUGE),)),
])
def test_a_selection_keeps_the_ranges_as_typed(text, ranges):
    selection = EpisodeSelection.parse(text)
    assert selection.ranges == ranges and bool(selection) == bool(ranges)
    assert EpisodeSelection.of(str(selection)) == selection  # its text (a report's) reads back as itself


@pytest.mark.parametrize("text", ["1_0", "+1", "-1", "x", "1-", "3-2", "1.0", "²", "٣", "1-2-3"])
def test_a_selection_is_digits_only(text):
    """Python's int() takes ``1_0`` (10), ``+1``, other scripts' digits; an episode list takes none of them."""
    with pytest.raises(ValueError):
        EpisodeSelection.parse(text)


def test_a_huge_range_is_answered_by_the_files_episodes_not_walked():
    """`pick` and `missing` cost what the file's episodes and the ranges cost, whatever the numbers."""
    selection = EpisodeSelection.parse(f"5,2-{HUGE},0")
    assert selection.pick(range(4)) == [2, 3, 0]  # in the order named, each once
    assert selection.missing({0, 1, 2, 3}, 3) == [5, 4, 6]
    assert selection.missing(range(10), 1) == [10]
    assert HUGE in selection and HUGE + 1 not in selection and 1 not in selection
    assert str(selection) == f"5,2-{HUGE},0"


def test_indices_are_one_range_each_in_their_order():
    selection = EpisodeSelection.of([3, 1, 1])
    assert list(selection) == [3, 1, 1] and selection.pick([1, 3]) == [3, 1] and selection.missing([1], 5) == [3]
    assert EpisodeSelection.of(None) is None and EpisodeSelection.of(selection) is selection
    assert list(EpisodeSelection.of(np.array([2, 0]))) == [2, 0]  # numpy's ints are indices too


@pytest.mark.parametrize(("value", "why"), [
    (5, "not a list of indices"),  # was: TypeError 'int' object is not iterable
    (b"01", "not a list of indices"),  # was: episodes 48 and 49
    ([0, 1.5], "1.5 is not a whole number"),  # was: TypeError
    ([True], "True is not a whole number"),  # was: episode 1
    ([-1], "-1 is negative"),  # was: a range naming no episode
    ("3-2", "range '3-2' runs backwards"),  # was: ValueError
])
def test_what_is_no_selection_is_one_usage_error_saying_what_to_give(value, why):
    with pytest.raises(UsageError) as refused:
        EpisodeSelection.of(value)
    assert str(refused.value) == (f"episodes={value!r}: {why}; give episode indices, ints >= 0 (e.g. [0, 3]), their "
                                  'text as --episodes takes it ("0,3-7"), or None (all)')
