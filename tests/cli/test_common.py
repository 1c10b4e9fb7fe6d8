"""Options several commands share: the tolerance options of `simreel replay` and `simreel view`."""

from __future__ import annotations

import argparse

import pytest

from simreel.cli.common import parse_group_tolerance, parse_tolerance
from simreel.cli.main import build_parser
from simreel.model.components import GROUPS, TOLERANCE_MODES
from simreel.replay.run.engine import MODES


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
    with pytest.raises(argparse.ArgumentTypeError, match="'inf': a tolerance must be a finite number >= 0"):
        parse_tolerance("inf")


def test_a_progress_line_off_a_terminal_counts_on_whatever_its_label_holds(capsys, monkeypatch):
    """Regression: off a terminal a line was told from the closing one by its text before the first "[", which a
    label holding a file name like run[2].h5 never changes: every line after the first was dropped."""
    import re

    import simreel.cli.common as common

    monkeypatch.setattr(common, "LOG_LINE_SECONDS", 0.0)
    for _ in common.progress_bar(range(3), quiet=False, desc="convert run[2].h5", unit="ep"):
        pass
    lines = capsys.readouterr().err.splitlines()
    assert [re.search(r"\| (\d)/3 \[", line).group(1) for line in lines] == ["0", "1", "2", "3"], lines
    assert all(line.startswith("convert run[2].h5: ") for line in lines)
