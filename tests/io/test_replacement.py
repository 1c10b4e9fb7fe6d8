"""A recording's files, and every output of one command, replaced as one unit (`simreel.io.replacement`): real
`merge` and `filter` processes killed, or racing each other, between two renames (a pause between them injected
through `PAUSE_VARIABLE`)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write
from support.processes import simreel_command

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.io.replacement import INTERRUPTED, PAUSE_VARIABLE, intent_path


@pytest.fixture()
def inputs(tmp_path) -> tuple[Path, Path]:
    meta = synthetic_meta()
    a = write(tmp_path / "a.h5", meta, [synthetic_episode(meta, i, 3) for i in range(3)])
    b = write(tmp_path / "b.h5", meta, [synthetic_episode(meta, i, 4, seed=5) for i in range(2)])
    return a, b


def _paused(*args: str, pause: float) -> subprocess.Popen:
    return subprocess.Popen(simreel_command(*args, "-q"), env={**os.environ, PAUSE_VARIABLE: str(pause)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _kill_after_first_rename(child: subprocess.Popen, sidecar: Path) -> None:
    """Kill `child` (-9) once it has moved its first file, `sidecar`, into place (it pauses after each rename)."""
    before = sidecar.read_bytes()
    deadline = time.monotonic() + 120
    while sidecar.read_bytes() == before:
        assert child.poll() is None, child.communicate()
        assert time.monotonic() < deadline, "the sidecar was never replaced"
        time.sleep(0.02)
    child.kill()
    child.communicate()


def _agrees(path: Path, episodes: int) -> None:
    """`path` holds `episodes` episodes and its sidecar lists just those (the reader notes no disagreement)."""
    with open_reader(path) as r:
        assert len(r.episodes) == episodes and r.notes == [], r.notes
        held = [(m.index, m.seed) for m in r.episodes]
    listed = [(e["episode_id"], e["episode_seed"]) for e in json.loads(path.with_suffix(".json").read_text())["episodes"]]
    assert listed == held


def test_a_merge_killed_between_its_renames_is_refused_by_readers_and_finished_by_recover(inputs, tmp_path, capsys):
    """Killed after it moved OUT.json and before OUT.h5, a merge --overwrite left the new sidecar beside the old .h5,
    which inspected clean (exit 0). Now every reader and writer of OUT refuses it in one line, and `recover OUT` does
    the renames that were left: OUT is then the new merge, whole."""
    a, b = inputs
    out = tmp_path / "out.h5"
    assert main(["merge", str(a), "-o", str(out), "-q"]) == 0
    _kill_after_first_rename(_paused("merge", str(b), "-o", str(out), "--overwrite", pause=60), out.with_suffix(".json"))
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 2
    assert capsys.readouterr().err == (f"simreel inspect: error: {out}: {INTERRUPTED}; `simreel recover {out}` finishes "
                                       "that replacement\n")
    assert main(["merge", str(a), "-o", str(out), "--overwrite", "-q"]) == 2  # no writer either
    assert "`simreel recover" in capsys.readouterr().err
    assert main(["recover", str(out)]) == 0
    said = capsys.readouterr().out
    assert said.startswith(f"finished replacing {out}: a command was stopped between its renames (1 of its 2 renames "
                           "were done)\n"), said
    _agrees(out, 2)
    assert not intent_path(out).exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_split_killed_between_its_outputs_is_finished_as_one_unit(inputs, tmp_path, capsys):
    """`filter --rest --overwrite` publishes OUT and REST as one unit: killed after its first rename, both are refused
    until `recover` of either finishes both (it once left a new OUT beside an old REST, episodes lost from both)."""
    a, _ = inputs
    kept, rest = tmp_path / "kept.h5", tmp_path / "rest.h5"
    assert main(["filter", str(a), "--episodes", "0", "-o", str(kept), "--rest", str(rest), "-q"]) == 0
    _kill_after_first_rename(_paused("filter", str(a), "--episodes", "0,1", "-o", str(kept), "--rest", str(rest),
                                     "--overwrite", pause=60), kept.with_suffix(".json"))
    for path in (kept, rest):
        assert main(["inspect", str(path)]) == 2
        assert INTERRUPTED in capsys.readouterr().err
    assert main(["recover", str(rest)]) == 0
    assert f"finished replacing {kept}, {rest}: " in capsys.readouterr().out
    _agrees(kept, 2)
    _agrees(rest, 1)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_merge_replacing_an_out_another_one_is_replacing_waits_and_leaves_its_own_whole(inputs, tmp_path):
    """Two `merge --overwrite` of other inputs to one OUT: the second begins its renames while the first pauses
    between its own (5 s after moving OUT.json). Unguarded, the first's .h5 came last, beside the second's sidecar
    (a mix, both exit 0). The second waits for the first's renames, then makes its own: OUT is the second's, whole."""
    a, b = inputs
    out = tmp_path / "out.h5"
    assert main(["merge", str(a), "-o", str(out), "-q"]) == 0
    first = _paused("merge", str(b), "-o", str(out), "--overwrite", pause=5)
    before = out.with_suffix(".json").read_bytes()
    deadline = time.monotonic() + 120
    while out.with_suffix(".json").read_bytes() == before:  # the first has moved its sidecar (b's episodes)
        assert first.poll() is None and time.monotonic() < deadline, first.communicate()
        time.sleep(0.02)
    second = subprocess.run(simreel_command("merge", str(a), "-o", str(out), "--overwrite", "-q"), capture_output=True,
                            text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    assert first.wait(timeout=120) == 0, first.communicate()
    _agrees(out, 3)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
