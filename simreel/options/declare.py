"""Each option of a command declared once: a dataclass field made by `option(...)` carries its default, its help,
its command-line spelling and its check, and everything else comes from that one declaration —

- `add_arguments(parser, Options)`: the command's argparse arguments (flags, defaults, help, choices, required
  options, mutually exclusive groups, ``--x``/``--no-x`` twins);
- `from_arguments(Options, args, ...)`: the options object from what argparse parsed;
- `check_options(self)`, called by the options' ``__post_init__``: every field's check, so a Python caller's
  wrong value is the same one-line `UsageError` as a command line's;
- `documented(cls)`: the class docstring's list of options, from the same help texts;
- `names_tagged(Options, tag)`: the options of one kind (e.g. those that decide a replay's verdicts).

Adding an option to a command is one `option(...)` field in its options class.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Option", "option", "add_option", "add_arguments", "from_arguments", "check_options", "documented",
           "names_tagged", "changed_on_command_line", "flags_of", "GivenOnce", "cli_names"]

_KEY = "simreel.option"
_SAME = object()
"""`Option.cli_default` when the command line's default is the field's own."""


@dataclass(frozen=True)
class Option:
    """How one option reads, on the command line and in Python.

    Attributes:
        help: one text for ``--help`` and the options class's docstring.
        flags: the command line's spellings (default: ``--<name>`` with ``-`` for ``_``); empty with ``cli=False``.
        metavar, choices, nargs, const, action: as argparse takes them; `choices` may be a function (called when
            the parser is built, so a heavy list is only made for ``--help``).
        parse: argparse's ``type``: the text of one value to the value.
        cli_default: the command line's default where it differs from the field's (e.g. ``[]`` for a repeated
            option whose field holds a dict).
        from_cli: what argparse holds to the field's value (e.g. ``dict`` for repeated ``GROUP=X`` pairs).
        check: ``check(name, value)`` returns the value in its one form or raises `UsageError` naming `name`.
        cli: False for an option only Python callers give (the command fills it itself).
        tags: kinds the command groups options by (`names_tagged`).
        required: the command line must give it (argparse's ``required``; a Python caller gives the field).
        group: the name of a mutually exclusive group: of the options of one class in the same group, the command
            line takes one at most (``--verified REPORT`` or ``--diverged REPORT``).
        negative: the help of the option's ``--no-<name>`` twin, for a yes/no/unset option (a field defaulting to
            None): the option's own flag sets True, the twin False, the command line takes one at most, and neither
            given leaves the default (``--success`` / ``--no-success``).
    """

    help: str
    flags: tuple[str, ...] = ()
    metavar: str | None = None
    choices: Sequence[str] | Callable[[], Sequence[str]] | None = None
    nargs: str | None = None
    const: Any = None
    action: Any = None
    parse: Callable[[str], Any] | None = None
    cli_default: Any = _SAME
    from_cli: Callable[[Any], Any] | None = None
    check: Callable[[str, Any], Any] | None = None
    cli: bool = True
    tags: frozenset[str] = frozenset()
    required: bool = False
    group: str | None = None
    negative: str | None = None


def option(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING, spec: Option | None = None,
           tags: Sequence[str] = (), **spelling: Any) -> Any:
    """A dataclass field that declares an option: `spec`, an option several commands share (with `spelling`'s changes),
    or one of its own (`spelling`: `Option`'s fields, `help` among them); `tags` are added to the spec's."""
    declared = dataclasses.replace(spec, **spelling) if spec is not None else Option(**spelling)
    declared = dataclasses.replace(declared, tags=declared.tags | frozenset(tags))
    return dataclasses.field(default=default, default_factory=default_factory, metadata={_KEY: declared})


def _declared(cls: type) -> Iterator[tuple[dataclasses.Field, Option]]:
    for f in dataclasses.fields(cls):
        if _KEY in f.metadata:
            yield f, f.metadata[_KEY]


def _default(f: dataclasses.Field, o: Option) -> Any:
    if o.cli_default is not _SAME:
        return o.cli_default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None if f.default is dataclasses.MISSING else f.default


def flags_of(name: str, o: Option) -> tuple[str, ...]:
    return o.flags or ("--" + name.replace("_", "-"),)


def add_option(parser: Any, dest: str, o: Option, default: Any) -> None:
    """Add the command-line option `o` to `parser` (an argparse parser or group), parsed into `dest` with `default`
    when not given; with `Option.negative`, its ``--no-`` twin too, in one mutually exclusive group."""
    if o.negative is not None:
        twins = parser.add_mutually_exclusive_group()
        flag = flags_of(dest, o)[-1]
        twins.add_argument(flag, dest=dest, action="store_const", const=True, default=default, help=o.help)
        twins.add_argument("--no-" + flag.removeprefix("--"), dest=dest, action="store_const", const=False,
                           help=o.negative)
        return
    kwargs: dict[str, Any] = {"dest": dest, "default": default, "help": o.help}
    choices = o.choices() if callable(o.choices) else o.choices
    extra = {"metavar": o.metavar, "choices": choices, "nargs": o.nargs, "const": o.const, "action": o.action,
             "type": o.parse, "required": o.required or None}
    kwargs.update({k: v for k, v in extra.items() if v is not None})
    parser.add_argument(*flags_of(dest, o), **kwargs)


def add_arguments(parser: argparse.ArgumentParser, cls: type, *, only: Sequence[str] | None = None) -> None:
    """Add every command-line option `cls` declares (those named in `only`, where given, in its order); the options
    of one `Option.group` go into one mutually exclusive group."""
    declared = {f.name: (f, o) for f, o in _declared(cls) if o.cli}
    groups: dict[str, Any] = {}
    for name in only if only is not None else declared:
        f, o = declared[name]
        if o.group is not None and o.group not in groups:
            groups[o.group] = parser.add_mutually_exclusive_group()
        add_option(parser if o.group is None else groups[o.group], f.name, o, _default(f, o))


def from_arguments(cls: type, args: argparse.Namespace, **given: Any) -> Any:
    """`cls` built from the options argparse parsed into `args` (each through its `Option.from_cli`), and `given`."""
    values = {}
    for f, o in _declared(cls):
        if o.cli and f.name not in given and hasattr(args, f.name):
            value = getattr(args, f.name)
            values[f.name] = o.from_cli(value) if o.from_cli is not None else value
    return cls(**values, **given)


def check_options(options: Any) -> None:
    """Run every declared check of a frozen options object, in declaration order, keeping each value in its form."""
    for f, o in _declared(type(options)):
        if o.check is not None:
            object.__setattr__(options, f.name, o.check(f.name, getattr(options, f.name)))


def cli_names(cls: type) -> tuple[str, ...]:
    """The names of the options of `cls` the command line takes, in declaration order."""
    return tuple(f.name for f, o in _declared(cls) if o.cli)


def names_tagged(cls: type, tag: str) -> tuple[str, ...]:
    """The names of the options of `cls` tagged `tag`, in declaration order."""
    return tuple(f.name for f, o in _declared(cls) if tag in o.tags)


def changed_on_command_line(cls: type, args: argparse.Namespace, names: Sequence[str]) -> list[str]:
    """The command-line flags among `names` whose value in `args` is not their default, or that were given (a
    `GivenOnce` option, even with its default value)."""
    declared = {f.name: (f, o) for f, o in _declared(cls)}
    given = vars(args).get("_given_once", {})
    return [flags_of(n, declared[n][1])[-1] for n in names
            if n in given or getattr(args, n, None) != _default(*declared[n])]


def documented(cls: type) -> type:
    """`cls` with its options listed at the end of its docstring, each with its help (a class decorator)."""
    lines = [f"        {f.name}: {o.help}" for f, o in _declared(cls)]
    cls.__doc__ = (cls.__doc__ or "").rstrip() + "\n\n    Options (each as its command-line help says):\n" + "\n".join(lines)
    return cls


class GivenOnce(argparse.Action):
    """An option that stores a list (`--episodes 0,3-7`, `--contacts A:B,C:D`, `--keep`) and refuses a second one: given
    twice, argparse kept the last list alone without a word, where `--episodes 0 --episodes 1` may well mean both."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        text = ",".join(values) if isinstance(values, tuple) else str(values)  # `--keep`'s type makes a tuple
        given = vars(namespace).setdefault("_given_once", {})
        if self.dest in given:
            raise argparse.ArgumentError(self, f"given twice ({given[self.dest]!r}, then {text!r}); give it once, "
                                               "with every item in one comma-separated list")
        given[self.dest] = text
        setattr(namespace, self.dest, values)
