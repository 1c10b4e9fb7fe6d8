"""`simreel filter`: the summary (kept of how many, the rest, notes on episodes without success, what was
checked), the criteria as options, and one-line refusals (exit 2)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.cli.main import main
from simreel.formats import open_reader


@pytest.fixture()
def src(tmp_path) -> Path:
    """Episodes of 3, 4, 5, 1 steps; final success False, True, False, and none (the file holds none)."""
    meta = synthetic_meta()
    episodes = []
    for i, (T, success) in enumerate(zip((3, 4, 5, 1), (False, True, False, None), strict=True)):
        ep = synthetic_episode(meta, i, T)
        episodes.append(dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, success=success)))
    return write(tmp_path / "src.h5", meta, episodes)


def _origins(path: Path) -> list[int]:
    with open_reader(path) as r:
        return [m.origin["index"] for m in r.episodes]


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
        ([], "no criterion: give --episodes, --success/--no-success, --min-steps or --max-steps"),
        (["--success", "--no-success"], "argument --no-success: not allowed with argument --success"),
        (["--episodes", "0,x"], "bad episode list '0,x': expected e.g. 0,3-7"),
        (["--episodes", ","], "--episodes ',' names no episode"),
        (["--episodes", "9"], "src.h5: no episode 9 (episodes: 0, 1, 2, 3)"),
        (["--min-steps", "6"], "nothing matches; nothing written"),
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
