"""`simreel export IN... --to lerobot OUT` on a real recording: the summary, the metadata that names the source files,
episodes and verdicts, `--keep` with a replay report, and one-line refusals (exit 2) that leave OUT as it was."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from support.nudged import nudged_copy

from simreel.cli.main import main
from simreel.formats import open_reader


@pytest.fixture(scope="module")
def nudged(record, tmp_path_factory) -> tuple[Path, Path]:
    """A PickCube recording (observations recorded) whose episode 1 had one action nudged, and its replay report:
    episodes 0 and 2 exact, 1 diverged."""
    folder = tmp_path_factory.mktemp("export")
    rec = nudged_copy(record("PickCube-v1", 3, 15, "--record-obs"), folder / "nudged.h5")
    report = folder / "report.json"
    assert main(["replay", str(rec), "--report", str(report), "-q"]) == 1
    return rec, report


def _status(args: list[str]) -> int:
    """`simreel ARGS`' exit status, a parse error's (argparse exits) included."""
    try:
        return main(args)
    except SystemExit as exit_:
        return int(exit_.code)


def _episodes(out: Path) -> list[dict]:
    return pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()


def _sources(out: Path) -> dict:
    return json.loads((out / "meta/info.json").read_text())["simreel"]


def test_an_export_names_its_source_files_and_episodes(nudged, tmp_path, capsys):
    rec, _ = nudged
    out = tmp_path / "ds"
    assert main(["export", str(rec), "--to", "lerobot", str(out)]) == 0
    assert capsys.readouterr().out.startswith(
        f"exported 3 episode(s), 45 frames at 20 fps from 1 recording(s) to {out} (LeRobot dataset v3.0: "
        "observation.state, action, next.reward")
    with open_reader(rec) as r:
        recording_id = r.meta.recording_id
    simreel = _sources(out)
    assert [(s["path"], s["recording_id"], s["episodes"]) for s in simreel["sources"]] == [
        (str(rec), recording_id, [0, 1, 2])]
    assert simreel["report"] is None and simreel["command"].startswith("simreel export ")
    # no report: no verdict for any episode, and none called verified
    assert [(e["simreel/source_file"], e["simreel/source_episode"], e["simreel/verdict"]) for e in _episodes(out)] == [
        (str(rec), k, None) for k in range(3)]


@pytest.mark.parametrize(("keep", "kept"), [([], [(0, "exact"), (2, "exact")]),
                                            (["--keep", "verified"], [(0, "exact"), (2, "exact")]),
                                            (["--keep", "diverged"], [(1, "diverged")]),
                                            (["--keep", "exact,diverged"], [(0, "exact"), (1, "diverged"),
                                                                            (2, "exact")])])
def test_keep_takes_the_episodes_of_the_reports_verdicts(nudged, tmp_path, capsys, keep, kept):
    rec, report = nudged
    out = tmp_path / "ds"
    assert main(["export", str(rec), "--to", "lerobot", str(out), "--report", str(report), *keep]) == 0
    assert capsys.readouterr().out.startswith(f"exported {len(kept)} episode(s), {15 * len(kept)} frames at 20 fps")
    assert [(e["simreel/source_episode"], e["simreel/verdict"]) for e in _episodes(out)] == kept
    simreel = _sources(out)
    assert simreel["report"] == str(report) and simreel["sources"][0]["episodes"] == [k for k, _ in kept]
    assert pq.read_table(out / "data/chunk-000/file-000.parquet").num_rows == 15 * len(kept)


@pytest.mark.parametrize(("args", "message"), [
    (["{tmp}/missing.h5", "--to", "lerobot", "{tmp}/ds"], "{tmp}/missing.h5: no such file"),
    (["{rec}", "--to", "rlds", "{tmp}/ds"], "--to rlds: simreel exports to lerobot"),
    (["{rec}", "--to", "lerobot", "{tmp}/ds", "--report", "{tmp}/nope.json"], "nope.json: no such report"),
    (["{rec}", "--to", "lerobot", "{tmp}/ds", "--report", "{report}", "--keep", "fine"],
     "argument --keep: expected verified or any of exact, within_tolerance, diverged, error, got 'fine'"),
    (["{rec}", "--to", "lerobot", "{tmp}/ds", "--state", "obs/nope"], "episode 0 has no obs/nope"),
    (["{report}", "--to", "lerobot", "{tmp}/ds"], "a replay report (`simreel replay --report`); give a recording"),
])
def test_bad_input_is_one_line_and_exit_2(nudged, tmp_path, capsys, args, message):
    rec, report = nudged
    values = {"tmp": tmp_path, "rec": rec, "report": report}
    assert _status(["export", *(a.format(**values) for a in args)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("simreel export: error: ") and err.count("\n") == 1, err
    assert message.format(**values) in err, err
    assert not (tmp_path / "ds").exists()


def test_an_existing_out_is_replaced_only_with_overwrite(nudged, tmp_path, capsys):
    rec, report = nudged
    out = tmp_path / "ds"
    assert main(["export", str(rec), "--to", "lerobot", str(out), "--report", str(report)]) == 0
    before = (out / "meta/info.json").read_bytes()
    capsys.readouterr()
    assert main(["export", str(rec), "--to", "lerobot", str(out)]) == 2
    assert capsys.readouterr().err == (f"simreel export: error: {out} already exists; pass --overwrite to replace it "
                                       "(overwrite=True from Python)\n")
    assert (out / "meta/info.json").read_bytes() == before
    assert main(["export", str(rec), "--to", "lerobot", str(out), "--overwrite"]) == 0
    assert len(_episodes(out)) == 3
