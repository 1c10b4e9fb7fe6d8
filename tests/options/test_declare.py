"""`simreel.options.declare`: one `option(...)` field gives a command's flag, its help, its Python check and its
groups; the replay, convert and audit commands take exactly the options their classes declare."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

from simreel.errors import UsageError
from simreel.options.checks import flag, whole
from simreel.options.declare import (
    add_arguments,
    changed_on_command_line,
    check_options,
    cli_names,
    documented,
    from_arguments,
    names_tagged,
    option,
)


@documented
@dataclass(frozen=True)
class _Options:
    """Options of a made-up command."""

    count: int = option(3, metavar="N", parse=int, tags=["verdict"], help="how many (default 3)",
                        check=whole("a count, an int"))
    loud: bool = option(False, action="store_true", help="say more", check=flag())
    pairs: dict = option(default_factory=dict, flags=("--pair",), action="append", parse=lambda t: tuple(t.split("=")),
                         cli_default=[], from_cli=dict, help="K=V, repeatable")
    note: str = option("", cli=False, help="set by the command itself")

    def __post_init__(self) -> None:
        check_options(self)


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser, _Options)
    return parser.parse_args(list(argv))


def test_one_declaration_gives_the_flag_its_default_help_and_the_options_object():
    args = _parse("--count", "5", "--pair", "a=1", "--pair", "b=2")
    options = from_arguments(_Options, args, note="from the command")
    assert options == _Options(count=5, loud=False, pairs={"a": "1", "b": "2"}, note="from the command")
    assert from_arguments(_Options, _parse()) == _Options()
    assert cli_names(_Options) == ("count", "loud", "pairs")
    assert names_tagged(_Options, "verdict") == ("count",)
    assert changed_on_command_line(_Options, _parse("--loud"), cli_names(_Options)) == ["--loud"]
    assert "count: how many (default 3)" in _Options.__doc__ and "note: set by the command itself" in _Options.__doc__


def test_the_declared_check_refuses_a_python_callers_wrong_value_with_one_usage_error():
    with pytest.raises(UsageError, match=r"^count='5': give a count, an int$"):
        _Options(count="5")
    with pytest.raises(UsageError, match=r"^loud='no': give True or False$"):
        _Options(loud="no")


def _flags(parser: argparse.ArgumentParser) -> set[str]:
    return {a.dest for a in parser._actions if a.dest != "help"}


@pytest.mark.parametrize(
    ("command", "module", "cls", "own"),
    [
        ("replay", "simreel.replay.run.options", "ReplayOptions", {"paths", "resume", "quiet"}),
        ("convert", "simreel.replay.convert.options", "ConvertOptions",
         {"input", "output", "poses", "report", "quiet"}),
        ("audit", "simreel.replay.audit.options", "AuditOptions",
         {"env_id", "policy", "episodes", "json", "overwrite", "quiet"}),
    ],
)
def test_a_command_takes_the_options_its_class_declares_and_only_its_own_besides(command, module, cls, own):
    from simreel.cli.main import build_parser

    options = getattr(__import__(module, fromlist=[cls]), cls)
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    assert _flags(sub) == set(cli_names(options)) | own
