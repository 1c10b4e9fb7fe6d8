"""JSON a file gives that cannot be read — nested deeper than Python follows, or bytes that are no UTF-8 — in a
ManiSkill sidecar, in a recording's `simreel_meta`, or in a replay report, is one line naming the file (exit 2) in
every command that reads it, never an internal error."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import pytest
from support.maniskill_files import copy_recording, record_maniskill

from simreel.cli.main import main
from simreel.datasets.inputs import file_identity
from simreel.formats.hdf5.layout import META_ATTR

DEEP = "[" * 100_000 + "]" * 100_000
"""Deeper than Python's json reads (RecursionError)."""
RATHER_DEEP = "[" * 500 + "]" * 500
"""Read by Python's json, but deeper than copying or writing it again can go."""


@pytest.fixture(scope="module")
def ms_dir(tmp_path_factory) -> Path:
    """A RecordEpisode file of PickCube-v1: 1 episode of 4 steps."""
    folder = tmp_path_factory.mktemp("maniskill")
    record_maniskill(folder, "PickCube-v1", name="demos", episodes=1, steps=4)
    return folder


def _deep_sidecar(ms_dir: Path, tmp_path: Path, deep: str) -> tuple[Path, Path]:
    path = copy_recording(ms_dir, "demos", tmp_path)
    side = path.with_suffix(".json")
    side.write_text(side.read_text().rstrip()[:-1] + f', "x": {deep}}}')
    return path, side


def _deep_meta(record, tmp_path: Path, deep: str) -> tuple[Path, Path]:
    path = tmp_path / "deep.h5"
    shutil.copy(record("PickCube-v1", 1, 4), path)
    with h5py.File(path, "r+") as f:
        meta = f.attrs[META_ATTR]
        meta = meta.decode() if isinstance(meta, bytes) else meta
        f.attrs[META_ATTR] = meta[:-1] + f',"x":{deep}}}'
    return path, path


def _commands(path: Path, other: Path, tmp_path: Path, report: Path) -> list[list[str]]:
    return [["inspect", str(path)], ["replay", str(path), "-q"], ["convert", str(path), str(tmp_path / "c.mcap")],
            ["merge", str(other), str(path), "-o", str(tmp_path / "m.h5")], ["recover", str(path), "-o",
            str(tmp_path / "recovered.h5")], ["filter", str(path), "-o", str(tmp_path / "filtered.h5"), "--verified", str(report)],
            ["view", str(path), "--save", str(tmp_path / "v.rrd")]]


@pytest.fixture(params=[("sidecar", DEEP), ("sidecar", RATHER_DEEP), ("simreel_meta", DEEP),
                        ("simreel_meta", RATHER_DEEP)],
                ids=["sidecar-too-deep-for-json", "sidecar-too-deep-to-copy", "meta-too-deep-for-json",
                     "meta-too-deep-to-copy"])
def deep_recording(request, ms_dir, record, tmp_path) -> tuple[Path, Path]:
    """(a recording, the file holding its too deeply nested JSON)."""
    where, deep = request.param
    return _deep_sidecar(ms_dir, tmp_path, deep) if where == "sidecar" else _deep_meta(record, tmp_path, deep)


def test_deeply_nested_json_in_a_recording_is_one_line_in_every_command(deep_recording, record, tmp_path, capsys):
    """Regression: each command ended with `internal error: RecursionError` (exit 3)."""
    path, named = deep_recording
    report = tmp_path / "r.json"
    size, mtime_ns = file_identity(path)
    report.write_text(json.dumps({"files": [{"path": str(path), "size": size, "mtime_ns": mtime_ns}],
                                  "episodes": [{"file": str(path), "index": 0, "verdict": "exact"}]}))
    capsys.readouterr()
    for args in _commands(path, record("PickCube-v1", 1, 4), tmp_path, report):
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is nested more than 100 levels deep" in err, (args, err)
        assert f"{named.name}: " in err, (args, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({path.name, named.name, "r.json"})


@pytest.mark.parametrize("text", [DEEP.encode(), b'{"files": [], "episodes": ["\xff"]}'], ids=["deep", "not-utf-8"])
def test_a_report_document_that_cannot_be_read_is_one_line(record, tmp_path, capsys, text):
    report = tmp_path / "r.json"
    report.write_bytes(text)
    capsys.readouterr()
    assert main(["filter", str(record("PickCube-v1", 1, 4)), "-o", str(tmp_path / "f.h5"), "--verified",
                 str(report)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"simreel filter: error: {report}: it is ") and err.count("\n") == 1, err
    assert "not a simreel replay report" in err


def test_bytes_that_are_no_utf_8_in_a_reports_lines_are_one_line(record, tmp_path, capsys):
    """Regression: `replay --resume` ended with `internal error: UnicodeDecodeError` (exit 3)."""
    report = tmp_path / "r.json"
    assert main(["replay", str(record("PickCube-v1", 1, 4)), "--report", str(report), "-q"]) == 0
    log = tmp_path / "r.jsonl"
    log.write_bytes(log.read_bytes().replace(b'"exact"', b'"ex\xffct"', 1))
    report.unlink()
    capsys.readouterr()
    assert main(["replay", "--resume", str(report), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"simreel replay: error: {log}: line ") and "is damaged" in err and err.count("\n") == 1
