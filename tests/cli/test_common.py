"""Options several commands share: the tolerance options of `simreel replay` and `simreel view`."""

from __future__ import annotations

import argparse

import pytest

from simreel.cli.common import parse_group_tolerance, parse_tolerance
from simreel.cli.main import build_parser
from simreel.compare import GROUPS, TOLERANCE_MODES
from simreel.replay.engine import MODES


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
