"""Replay reports: notes that limit a verdict, and the worst keys ranked like the comparison ranks them."""

from __future__ import annotations

from simreel.replay.run.verify import EpisodeReport, ReplayReport
from simreel.verdicts.compare import EpisodeComparison


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


def test_the_keys_said_to_have_left_their_tolerance_are_those_that_did():
    """The line under a diverged episode names the other keys that left their tolerance, never one within it."""
    from simreel.replay.report.report import episode_lines
    from simreel.verdicts.compare import Divergence

    errors = {"obs/qpos": 0.5, "rewards": 0.2, "env_states/cube": 3e-6}
    tol = {"obs/qpos": 1e-3, "rewards": 1e-3, "env_states/cube": 1e-5}
    rep = EpisodeReport(index=0, seed=0, length=9, verdict="diverged",
                        first_divergence=Divergence(step=4, key="obs/qpos", error=0.5, tolerance=1e-3),
                        max_abs_error=errors, tolerance=tol, diverged_keys={"obs/qpos": 4, "rewards": 6})
    (line,) = [x for x in episode_lines(rep) if "left their tolerance" in x]
    assert line.strip() == "2 keys left their tolerance; worst: rewards 0.2 (tol 0.001)"
