"""`simreel.options.declare`: one `option(...)` field gives a command's flag, its help, its Python check and its
groups; the replay, convert and audit commands take exactly the options their classes declare."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from typing import Any

import pytest

from simreel.errors import UsageError
from simreel.options.checks import flag, whole
from simreel.options.declare import (
    add_arguments,
    changed_on_command_line,
    check_options,
    cli_names,
    documented,
    flags_of,
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
        ("merge", "simreel.datasets.options", "DatasetOptions", {"inputs", "output", "quiet"}),
    ],
)
def test_a_command_takes_the_options_its_class_declares_and_only_its_own_besides(command, module, cls, own):
    from simreel.cli.main import build_parser

    options = getattr(__import__(module, fromlist=[cls]), cls)
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    assert _flags(sub) == set(cli_names(options)) | own


@dataclass(frozen=True)
class _Choices:
    """A made-up command's yes/no/unset option and a group of two options of which one at most is given."""

    success: bool | None = option(None, help="the successful ones", negative="the others")
    kept: str | None = option(None, group="report", help="what a report kept")
    dropped: str | None = option(None, group="report", help="what a report dropped")
    out: str = option("", flags=("-o",), required=True, help="the file to write")


def _parser_of(cls: type) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="made-up")
    add_arguments(parser, cls)
    return parser


@pytest.mark.parametrize(("argv", "success"), [([], None), (["--success"], True), (["--no-success"], False)])
def test_a_negative_option_is_a_flag_and_its_no_twin_and_neither_leaves_the_default(argv, success):
    assert from_arguments(_Choices, _parser_of(_Choices).parse_args([*argv, "-o", "x"])) == _Choices(success=success,
                                                                                                     out="x")


@pytest.mark.parametrize(("argv", "message"), [
    (["--success", "--no-success", "-o", "x"], "argument --no-success: not allowed with argument --success"),
    (["--kept", "a", "--dropped", "b", "-o", "x"], "argument --dropped: not allowed with argument --kept"),
    (["--kept", "a"], "the following arguments are required: -o"),
])
def test_a_group_and_a_negative_twin_take_one_at_most_and_a_required_option_must_be_given(argv, message, capsys):
    with pytest.raises(SystemExit):
        _parser_of(_Choices).parse_args(argv)
    assert capsys.readouterr().err.splitlines()[-1] == f"made-up: error: {message}"


def test_the_options_of_one_group_are_given_alone_and_the_help_shows_each_twin():
    args = _parser_of(_Choices).parse_args(["--dropped", "b", "-o", "x"])
    assert from_arguments(_Choices, args) == _Choices(dropped="b", out="x")
    usage = _parser_of(_Choices).format_usage()
    assert "[--success | --no-success]" in usage and "[--kept KEPT | --dropped DROPPED]" in usage
    assert "the others" in _parser_of(_Choices).format_help()


_COMMANDS = {
    "replay": ["simreel.replay.run.options:ReplayOptions"],
    "convert": ["simreel.replay.convert.options:ConvertOptions"],
    "audit": ["simreel.replay.audit.options:AuditOptions"],
    "record": ["simreel.cli.record:RecordRun", "simreel.recorders.options:RecordOptions",
               "simreel.cli.common:EnvOptions"],
    "merge": ["simreel.cli.merge:MergeRun", "simreel.datasets.options:DatasetOptions"],
    "filter": ["simreel.cli.filter:FilterRun", "simreel.datasets.options:EpisodeCriteria",
               "simreel.datasets.options:DatasetOptions"],
    "recover": ["simreel.cli.recover:RecoverRun"],
}
"""Each command whose options are declared, and the classes that declare them."""


def _declared_options(command: str) -> list[tuple[str, Any]]:
    found = []
    for where in _COMMANDS[command]:
        module, cls = where.split(":")
        declared = getattr(__import__(module, fromlist=[cls]), cls)
        found += [(f.name, f.metadata["simreel.option"]) for f in dataclasses.fields(declared)
                  if "simreel.option" in f.metadata and f.metadata["simreel.option"].cli]
    return found


@pytest.mark.parametrize("command", sorted(_COMMANDS))
def test_a_commands_help_lists_every_option_it_declares_with_its_help(command):
    from simreel.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    shown = " ".join(sub.format_help().split())  # the help, its lines joined
    missing = [name for name, o in _declared_options(command)
               if not all(flag in shown for flag in flags_of(name, o)) or " ".join(o.help.split()[:6]) not in shown]
    assert not missing
