"""Reports and messages: notes that limit a verdict, the worst keys, layout differences, audit wording, and
the tolerance options `simreel replay` and `simreel view` share."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from simreel.cli.common import parse_group_tolerance, parse_tolerance
from simreel.cli.main import build_parser
from simreel.compare import GROUPS, TOLERANCE_MODES, EpisodeComparison, Tolerances
from simreel.replay.audit_checks import AuditReport, Check, compare_states
from simreel.replay.engine import MODES
from simreel.replay.verify import EpisodeReport, ReplayReport
from simreel.state_tree import LeafSpec, layout_differences


def _report(verdict: str, notes: list[str], limits: list[str]) -> ReplayReport:
    ep = EpisodeReport(index=0, seed=None, length=3, verdict=verdict, first_divergence=None, max_abs_error={},
                       notes=notes, limits=limits)
    return ReplayReport(path="r.h5", env_id="PickCube-v1", mode="actions", resync=None, tolerances={}, episodes=[ep])


def test_notes_that_limit_the_check_show_even_when_exact():
    limit = "contacts not compared: the rebuilt scene has no body 'cube'"
    text = _report("exact", ["rebuilt the scene with seed 4", limit], [limit]).summary()
    assert f"note: {limit}" in text
    assert "rebuilt the scene" not in text  # how it was done: only worth a line when the episode is not exact
    text = _report("within_tolerance", ["rebuilt the scene with seed 4", limit], [limit]).summary()
    assert "note: rebuilt the scene with seed 4" in text and text.count(limit) == 1
    assert _report("exact", [limit], [limit]).to_json()["episodes"][0]["limits"] == [limit]


def test_episode_report_ranks_keys_like_the_comparison():
    errors = {"a": 2e-5, "b": 0.0, "c": 1.0, "flag": 1.0}
    tol = {"a": 1e-5, "b": 1e-5, "c": 1e-3, "flag": 0.0}
    cmp = EpisodeComparison(verdict="diverged", first_divergence=None, max_abs_error=errors, tolerance=tol)
    rep = EpisodeReport(index=0, seed=0, length=1, verdict="diverged", first_divergence=None, max_abs_error=errors,
                        tolerance=tol)
    assert rep.worst(3) == cmp.worst(3) == [("flag", 1.0, 0.0), ("c", 1.0, 1e-3), ("a", 2e-5, 1e-5)]


def test_layout_differences_name_each_leaf():
    old = {"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((1,), "float32")}
    new = {"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((2,), "float32"), "extra": LeafSpec((), "int64")}
    assert layout_differences(old, new, new_label="replay") == [
        "extra: recorded absent, replay () int64",
        "goal: recorded (1,) float32, replay (2,) float32",
    ]
    assert layout_differences(old, old) == []


def test_audit_names_a_key_missing_after_the_restore():
    report = AuditReport(env_id="X-v1", seed=0, steps=1)
    a = np.zeros((1, 3), np.float32)
    check = Check("restore_state", Tolerances.for_mode("states"), why="why")
    compare_states(report, check, {"gone": a, "kept": a}, {"kept": a, "new": a})
    details = {f.key: f.detail for f in report.findings}
    assert details["env_states/gone"] == "state key 'gone' missing after the restore: why"
    assert details["env_states/new"] == "state key 'new' present only after the restore: why"


@pytest.mark.parametrize("command", ["replay", "view"])
def test_replay_and_view_share_the_tolerance_options(command):
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    options = {o: a for a in sub.choices[command]._actions for o in a.option_strings}
    assert tuple(options["--mode"].choices) == MODES
    assert options["--tol"].type is parse_group_tolerance and options["--atol"].type is parse_tolerance


def test_tolerance_parsing():
    assert set(MODES) | {"resync"} == set(TOLERANCE_MODES)
    assert parse_group_tolerance("contact=5") == ("contact", 5.0)
    for group in GROUPS:
        if group != "flag":
            assert parse_group_tolerance(f"{group}=0")[0] == group
    for bad, message in [
        ("flag=1", "expected GROUP=NUMBER with GROUP one of pos, quat,"),
        ("speed=1", "got 'speed=1'"),
        ("pos", "expected GROUP=NUMBER"),
        ("pos=x", "'pos=x': 'x' is not a number"),
        ("pos=-1", "a tolerance must be a finite number >= 0"),
        ("pos=inf", "a tolerance must be a finite number >= 0"),
        ("pos=nan", "a tolerance must be a finite number >= 0"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            parse_group_tolerance(bad)
    assert parse_tolerance("1e-3") == 1e-3
    with pytest.raises(argparse.ArgumentTypeError, match="must be a finite number >= 0, got inf"):
        parse_tolerance("inf")
