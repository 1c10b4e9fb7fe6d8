"""A run's tally (`simreel.replay.report.tally`): counts per file, each episode once, memory that does not grow with the
run (rows only for small runs, a bounded list of what did not verify), the exit status and the summary."""

from __future__ import annotations

from simreel.replay.report.report import EpisodeReport
from simreel.replay.report.tally import LISTED, SHOWN_ROWS, FileTally, RunTally
from simreel.verdicts.compare import Divergence


def _report(index: int, verdict: str = "exact", length: int = 10) -> EpisodeReport:
    first = Divergence(step=3, key="env_states/actors/cube[p]", error=0.5, tolerance=1e-5) if verdict == "diverged" else None
    errors = {"env_states/actors/cube[p]": 0.5} if first else {}
    return EpisodeReport(index=index, seed=index, length=length, verdict=verdict, first_divergence=first,
                         max_abs_error=errors, tolerance={k: 1e-5 for k in errors})


def _tally(*files: tuple[str, int]) -> RunTally:
    tally = RunTally("actions", None, {"pos": 1e-5})
    for path, planned in files:
        tally.add_file(FileTally(path, "PickCube-v1", planned))
    return tally


def test_counts_per_file_and_each_episode_once():
    tally = _tally(("/d/a.h5", 2), ("/d/b.h5", 1))
    assert tally.add("/d/a.h5", _report(0)) and tally.add("/d/a.h5", _report(1, "diverged"))
    assert not tally.add("/d/a.h5", _report(1))  # a retried episode: its first verdict stands
    assert not tally.complete and tally.planned == 3 and tally.total == 2
    tally.add("/d/b.h5", _report(0, "within_tolerance"))
    assert tally.complete and not tally.ok and tally.exit_status() == 1
    head = tally.head()
    assert head["totals"] == {"exact": 1, "within_tolerance": 1, "diverged": 1, "error": 0, "files": 2,
                              "unreadable_files": 0, "episodes": 3, "planned": 3, "steps": 30}
    assert head["files"][0]["counts"] == {"exact": 1, "within_tolerance": 0, "diverged": 1, "error": 0}


def test_errors_and_unreadable_files_make_the_run_bad_input():
    tally = _tally(("/d/a.h5", 1))
    tally.add("/d/a.h5", EpisodeReport.errored(0, 10, "/d/a.h5: traj_0 lacks a dataset: 'actions'"))
    assert tally.exit_status() == 2 and "1 could not be replayed" in tally.summary()
    tally = _tally(("/d/a.h5", 1))
    tally.add_file(FileTally("/d/junk.h5", error="neither an HDF5 nor an MCAP file"))
    tally.add("/d/a.h5", _report(0))
    assert tally.exit_status() == 2 and not tally.ok
    assert "1 file(s) unreadable" in tally.summary() and "cannot be replayed: neither an HDF5" in tally.summary()


def test_a_small_run_keeps_every_row_a_large_one_only_what_did_not_verify_and_at_most_listed():
    tally = _tally(("/d/a.h5", SHOWN_ROWS + LISTED + 50))
    for i in range(SHOWN_ROWS):
        tally.add("/d/a.h5", _report(i, "diverged" if i == 5 else "exact"))
    assert len(tally.rows) == SHOWN_ROWS
    tally.add("/d/a.h5", _report(SHOWN_ROWS))
    assert [r.index for _, r in tally.rows] == [5]
    for i in range(SHOWN_ROWS + 1, SHOWN_ROWS + LISTED + 50):
        tally.add("/d/a.h5", _report(i, "diverged"))
    assert len(tally.rows) == LISTED and tally.more == 50
    text = tally.summary()
    assert "... and 50 more that did not verify" in text
    assert f"{SHOWN_ROWS} of {SHOWN_ROWS + LISTED + 50} episode(s) verified" in text


def test_one_file_prints_its_episode_table_many_print_a_line_per_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    one = _tally((str(tmp_path / "a.h5"), 2))
    one.add(str(tmp_path / "a.h5"), _report(1, "diverged"))
    one.add(str(tmp_path / "a.h5"), _report(0))
    lines = one.summary().splitlines()
    assert lines[0] == "replay of a.h5: PickCube-v1, mode actions, 2 episode(s), 20 steps"
    assert lines[2].split() == ["0", "10", "exact"] and lines[3].split()[:3] == ["1", "10", "diverged"]
    many = _tally((str(tmp_path / "a.h5"), 1), (str(tmp_path / "b.h5"), 2))
    many.add(str(tmp_path / "a.h5"), _report(0))
    many.add(str(tmp_path / "b.h5"), _report(1, "diverged"))
    text = many.summary()
    assert text.splitlines()[0] == "replay of 2 recordings (1 env id(s)), mode actions: 2 episode(s), 20 steps"
    assert "b.h5" in text and "(1 not replayed)" in text and "episodes that did not verify:" in text
    assert text.endswith("1 of 2 episode(s) verified (1 exact, 0 within tolerance); 1 diverged; "
                         "1 not replayed (the run stopped early)")


def test_a_run_with_episodes_left_without_a_verdict_never_exits_0():
    tally = _tally(("/d/a.h5", 2))
    tally.add("/d/a.h5", _report(0))
    assert not tally.complete and tally.exit_status() == 2
    assert tally.summary().endswith("1 not replayed (the run stopped early)")
