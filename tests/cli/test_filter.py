"""`simreel filter`: the summary (kept of how many, the rest, notes on episodes without success, what was
checked), the criteria as options, and one-line refusals (exit 2)."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.cli.main import main
from simreel.formats import open_reader

SUPPORT = Path(__file__).resolve().parents[1] / "support"


@pytest.fixture()
def src(tmp_path) -> Path:
    """Episodes of 3, 4, 5, 1 steps; final success False, True, False, and none (the file holds none)."""
    meta = synthetic_meta()
    episodes = []
    for i, (T, success) in enumerate(zip((3, 4, 5, 1), (False, True, False, None), strict=True)):
        ep = synthetic_episode(meta, i, T)
        episodes.append(dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, success=success)))
    return write(tmp_path / "src.h5", meta, episodes)


def _files(folder: Path) -> dict[str, bytes]:
    """The recordings in `folder` (not the hidden staging files of a command still running), by name."""
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")}


def _origins(path: Path) -> list[int]:
    with open_reader(path) as r:
        return [m.origin.index for m in r.episodes]


def test_a_split_by_success_says_what_went_where(src, tmp_path, capsys):
    kept, rest = tmp_path / "ok.h5", tmp_path / "rest.mcap"
    assert main(["filter", str(src), "-o", str(kept), "--rest", str(rest), "--success", "-q"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"filter src.h5 (success): kept 1 of 4, 1 episode(s), 4 steps → {kept} (")
    assert lines[1].startswith(f"rest: 3 episode(s), 9 steps → {rest} (")
    assert lines[2] == "note: 1 episode(s) hold no final success: neither --success nor --no-success keeps them"
    assert lines[3] == "checked: 4 episodes, every array equal to its source"
    assert (_origins(kept), _origins(rest)) == ([1], [0, 2, 3])


@pytest.mark.parametrize(
    ("options", "kept"),
    [
        (["--episodes", "0,2-3"], [0, 2, 3]),
        (["--no-success"], [0, 2]),
        (["--min-steps", "4"], [1, 2]),
        (["--max-steps", "3", "--episodes", "1-3"], [3]),
        (["--min-steps", "3", "--max-steps", "4", "--no-success"], [0]),
    ],
)
def test_criteria_combine_with_and(src, tmp_path, options, kept):
    out = tmp_path / "out.mcap"
    assert main(["filter", str(src), "-o", str(out), *options, "-q"]) == 0
    assert _origins(out) == kept


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ([], "no criterion: give --episodes, --success/--no-success, --min-steps, --max-steps, --verified or --diverged"),
        (["--success", "--no-success"], "argument --no-success: not allowed with argument --success"),
        (["--verified", "r.json", "--diverged", "r.json"], "argument --diverged: not allowed with argument --verified"),
        (["--episodes", "0,x"], "bad episode list '0,x': expected e.g. 0,3-7"),
        (["--episodes", ","], "--episodes ',' names no episode"),
        (["--episodes", "9"], "src.h5: no episode 9 (episodes: 0, 1, 2, 3)"),
        (["--min-steps", "6"], "nothing matches (of 4 episode(s): 0 meet >= 6 steps); nothing written"),
        (["--success", "--episodes", "0,3"],
         "nothing matches (of 4 episode(s): 2 meet episodes 0,3, 1 meet success, none all; 1 episode(s) hold no "
         "final success: neither --success nor --no-success keeps them); nothing written"),
        (["--min-steps", "4", "--max-steps", "3"], "--min-steps 4 is above --max-steps 3: no episode fits"),
        (["--max-steps", "two"], "argument --max-steps: invalid int value: 'two'"),
        (["--success", "--rest", "{out}"], "--rest {out} is also written by -o; write it to another file"),
        (["--success", "--rest", "{tmp}/src.hdf5"], "--rest {tmp}/src.json is a file of input {tmp}/src.h5"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(src, tmp_path, capsys, options, message):
    out = tmp_path / "out.h5"
    options = [o.format(out=out, tmp=tmp_path) for o in options]
    try:
        code = main(["filter", str(src), "-o", str(out), *options, "-q"])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message.format(out=out, tmp=tmp_path) in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src.h5", "src.json"]


# ------------------------------------------------------------------------------------------ a replay's verdicts
@pytest.fixture(scope="module")
def replayed(record, tmp_path_factory) -> tuple[Path, Path, Path]:
    """A PickCube recording whose episode 1 had one action nudged, its full replay report (episode 0 exact,
    1 diverged), and the report of a replay of episode 0 alone."""
    from simreel.formats import open_writer

    folder = tmp_path_factory.mktemp("verdicts")
    rec = folder / "nudged.h5"
    with open_reader(record("PickCube-v1", 2, 20)) as r, open_writer(rec, r.meta) as w:
        for m in r.episodes:
            episode = r.read_episode(m.index)
            episode.actions[5] += 0.5 * (m.index == 1)
            w.write_episode(episode)
    full, partial = folder / "full.json", folder / "partial.json"
    assert main(["replay", str(rec), "--report", str(full), "-q"]) == 1
    assert main(["replay", str(rec), "--episodes", "0", "--report", str(partial), "-q"]) == 0
    return rec, full, partial


@pytest.mark.parametrize(("option", "split"), [("--verified", ([0], [1])), ("--diverged", ([1], [0]))])
def test_a_replay_reports_verdicts_split_a_recording(replayed, tmp_path, capsys, option, split):
    rec, full, _ = replayed
    out, other = tmp_path / "out.mcap", tmp_path / "rest.h5"
    assert main(["filter", str(rec), "-o", str(out), "--rest", str(other), option, str(full), "-q"]) == 0
    assert (_origins(out), _origins(other)) == split
    verdicts = "exact or within_tolerance" if option == "--verified" else "diverged"
    assert capsys.readouterr().out.startswith(f"filter nudged.h5 ({verdicts} in full.json): kept 1 of 2")
    with open_reader(out) as r:
        assert r.meta.provenance["criteria"] == {"report": str(full), "verdicts": verdicts.split(" or ")}


def test_episodes_a_report_does_not_cover_are_not_kept_and_counted(replayed, tmp_path, capsys):
    rec, _, partial = replayed
    assert main(["filter", str(rec), "-o", str(tmp_path / "ok.h5"), "--verified", str(partial), "-q"]) == 0
    out = capsys.readouterr().out
    assert "kept 1 of 2" in out and "note: 1 episode(s) are not in the replay report: not kept" in out
    assert _origins(tmp_path / "ok.h5") == [0]
    assert main(["filter", str(rec), "-o", str(tmp_path / "bad.h5"), "--diverged", str(partial), "-q"]) == 2
    assert ("nothing matches (of 2 episode(s): 0 meet diverged in partial.json; 1 episode(s) are not in the replay "
            "report: not kept); nothing written") in capsys.readouterr().err


def test_a_split_whose_rest_another_command_wrote_meanwhile_publishes_neither(src, tmp_path):
    """filter -o A --rest B, paused in its copy while another command writes B: at its end neither A nor B is
    published by it (a split is both files or none), and B stays the other command's."""
    kept, rest = tmp_path / "a.h5", tmp_path / "b.h5"
    split = subprocess.Popen([sys.executable, str(SUPPORT / "paused_copy.py"), "filter", str(src), "-o", str(kept),
                              "--rest", str(rest), "--episodes", "0-1"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert split.stdout.readline().strip() == "copying"
        assert main(["filter", str(src), "-o", str(rest), "--episodes", "3", "-q"]) == 0
        theirs = _files(tmp_path)
        _, err = split.communicate("go on\n", timeout=120)
    finally:
        split.kill()
    assert split.returncode == 2 and err.startswith(f"simreel filter: error: {rest} was written by another command"), err
    assert _files(tmp_path) == theirs and not kept.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # its staging files are gone


def test_a_report_made_before_the_sidecar_changed_is_refused(replayed, tmp_path, capsys):
    """The JSON sidecar is part of the recording (a ManiSkill file's episode list and seeds are there): a report made
    before it changed is about another recording."""
    rec, full, _ = replayed
    copy = tmp_path / "copy.h5"
    for suffix in (".h5", ".json"):
        shutil.copy2(rec.with_suffix(suffix), copy.with_suffix(suffix))  # the same bytes and times
    copy_report = tmp_path / "full.json"
    copy_report.write_text(full.read_text().replace(str(rec), str(copy)))
    assert main(["filter", str(copy), "-o", str(tmp_path / "y.h5"), "--verified", str(copy_report), "-q"]) == 0
    sidecar = json.loads(copy.with_suffix(".json").read_text())
    sidecar["episodes"][1]["episode_seed"] = 7
    copy.with_suffix(".json").write_text(json.dumps(sidecar))
    assert main(["filter", str(copy), "-o", str(tmp_path / "z.h5"), "--verified", str(copy_report), "-q"]) == 2
    assert f"{copy} changed since {copy_report} verified it" in capsys.readouterr().err


def test_a_report_of_another_file_or_of_the_file_before_it_changed_is_refused(replayed, src, tmp_path, capsys):
    rec, full, _ = replayed
    assert main(["filter", str(src), "-o", str(tmp_path / "x.h5"), "--verified", str(full), "-q"]) == 2
    assert capsys.readouterr().err == (f"simreel filter: error: {full} holds no verdict for {src}: replay it with "
                                       f"--report first (simreel replay {src} --report REPORT.json)\n")
    changed = tmp_path / "nudged.h5"
    changed.write_bytes(rec.read_bytes())
    copy_report = tmp_path / "full.json"
    copy_report.write_text(full.read_text().replace(str(rec), str(changed)))  # the report, naming the copy
    assert main(["filter", str(changed), "-o", str(tmp_path / "y.h5"), "--verified", str(copy_report), "-q"]) == 2
    assert f"{changed} changed since {copy_report} verified it" in capsys.readouterr().err
    assert main(["filter", str(rec), "-o", str(tmp_path / "z.h5"), "--verified", str(tmp_path / "no.json")]) == 2
    assert "no.json: no such report" in capsys.readouterr().err
