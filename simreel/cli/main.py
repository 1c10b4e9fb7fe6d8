"""The `simreel` command: one subcommand module per verb, imported only as far as argparse needs.

Exit status: 0 success, 1 a verdict that failed (replay diverged, audit findings), 2 bad input (one line on
stderr), 3 an internal error (one line), 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), 141 stdout closed (a
pipe into `head`). `--debug` prints the traceback before that line and changes nothing else: the exit status is the
same with it as without. SIGTERM is handled like Ctrl-C: the command stops where it is and cleans up (a recording
closes its file with every committed episode); a commit in progress finishes first (`simreel.io.durable`),
and so does an import of mani_skill (`simreel.sim.user_code.native_import`).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import shlex
import signal
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path

from simreel import __version__
from simreel.cli.common import STOPPED_THEN
from simreel.errors import SimreelError, Terminated
from simreel.io.durable import stop_raised, stopping_signals

__all__ = ["main", "run", "COMMANDS"]

COMMANDS = ("record", "inspect", "replay", "audit", "convert", "recover", "merge", "filter", "export", "view",
            "video")
"""Subcommand modules under simreel.cli; each has `add_parser(subparsers)` and `run(args) -> int`."""


class _OneLineParser(argparse.ArgumentParser):
    """argparse, but a bad option is one line on stderr (not usage + error) and exit 2, which says how to name a file
    whose name begins with '-' where one was taken for an option."""

    _given: list[str] = []
    """The arguments this parser was last given (`parse_known_args`; a subcommand's parser gets its own)."""

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[no-untyped-def,override]
        self._given = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> None:  # type: ignore[override]
        dashed = self._dashed_file_name()
        hint = f"{dashed} is taken for an option: write ./{dashed} for the file; " if dashed else ""
        sys.stderr.write(f"{self.prog}: error: {message} ({hint}see {self.prog} --help)\n")
        sys.exit(2)

    def _dashed_file_name(self) -> str | None:
        """The first argument (before any ``--``) that argparse took for an option but that is no option of this parser
        and names a file (one that exists, or a name with a suffix such as ``-x.h5``; not a number), or None. Which
        message argparse gives then misleads ("the following arguments are required: PATH", "expected one argument")."""
        given = self._given[:self._given.index("--")] if "--" in self._given else self._given
        for arg in given:
            if len(arg) < 2 or not arg.startswith("-") or "=" in arg or arg in self._option_string_actions:
                continue
            try:
                float(arg)
                continue
            except ValueError:
                pass
            if os.path.lexists(arg) or Path(arg).suffix:
                return arg
        return None


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog="simreel",
        description="Record, replay-and-verify, audit and view ManiSkill 3 trajectories.",
    )
    parser.add_argument("--version", action="version", version=f"simreel {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_OneLineParser)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"simreel.cli.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"simreel.cli.{name}":
                raise
            continue
        module.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command of `argv` (None: the process's arguments); its exit status."""
    with stopping_signals():
        return _parse_and_run(argv)


def run() -> None:
    """The `simreel` executable (and ``python -m simreel``): `main`, then exit with its status. Once the command has
    finished, SIGINT and SIGTERM are ignored: the interpreter takes ~0.6 s to exit after an import of torch, and a
    Ctrl-C then killed the process (exit 130, no word; or a KeyboardInterrupt traceback from Python's shutdown) after
    a command that had done all its work. An ignored signal stays ignored through that shutdown, where a handler would
    not (Python resets those first). They are ignored before `main` begins, which puts back what it found when the
    command ends: set after `main` returned, a signal that came late (a Ctrl-C held while worker processes started,
    then handled) met Python's own handler in between and killed the process by SIGINT after the command's one line.
    In-process callers use `main`, which leaves the signals as it found them."""
    for stop in (signal.SIGINT, signal.SIGTERM):
        signal.signal(stop, signal.SIG_IGN)
    _open_standard_streams()
    sys.exit(main())


def _open_standard_streams() -> None:
    """Put /dev/null on each of descriptors 0, 1 and 2 that the process was started without (`cmd <&- >&- 2>&-`), and
    give Python a stream for it. Else the next file or pipe opened takes the lowest free number: a writer child's pipe
    on 0 or 1 was replaced by its own /dev/null stdin/stdout (`record` failed: "the writer process ended"), a
    recording opened on 1 or 2 would take whatever a library or child prints there, and `sys.stderr`, None, made the
    one line of an error an AttributeError (exit 1). What would have gone to a closed stream is dropped, as before."""
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        try:
            os.fstat(fd)
            continue
        except OSError:
            pass
        null = os.open(os.devnull, os.O_RDWR)  # the lowest free descriptor: `fd` itself
        if null != fd:
            os.dup2(null, fd)
            os.close(null)
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, mode, closefd=False, encoding="utf-8", errors="backslashreplace"))


def _command_parser(parser: argparse.ArgumentParser, command: str | None) -> argparse.ArgumentParser:
    """The parser of subcommand `command` (`parser` itself where none was given)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and command in action.choices:
            return action.choices[command]
    return parser


def _parse_and_run(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        argv = list(sys.argv[1:] if argv is None else argv)
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # said by the command's parser, which names its own --help (argparse's top parser would not)
            _command_parser(parser, args.command).error(f"unrecognized arguments: {' '.join(unknown)}")
    except KeyboardInterrupt as e:  # Terminated (SIGTERM) is one too
        return _stopped("simreel", e)
    args.command_line = shlex.join(["simreel", *argv])  # stored in recordings for provenance
    if not args.command:
        parser.print_help()
        return 2
    return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the command; its exceptions become the exit status and one line on stderr."""
    try:
        return int(args.run(args) or 0)
    except SimreelError as e:
        _fail(args, f"error: {e}")
        return 2
    except KeyboardInterrupt as e:  # Terminated (SIGTERM) is one too
        return _stopped(f"simreel {args.command}", e)
    except BrokenPipeError:  # `simreel inspect x | head`: the reader left; say nothing more, as shell tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as e:  # a bug, not bad input: still one line, and not 1 (which replay uses for "diverged")
        stop = stop_raised()
        if stop is not None:  # a Ctrl-C some library swallowed, and what it left half made failed: the signal's doing
            if args.debug:
                traceback.print_exc()
            return _stopped(f"simreel {args.command}", stop)
        return _unexpected(args, e)


def _stopped(prog: str, stop: KeyboardInterrupt) -> int:
    """The exit status and one line of a command stopped by SIGTERM (`Terminated`) or Ctrl-C, ending with what the
    command kept and how to finish (`stopped_saying`), where it says."""
    then = getattr(stop, STOPPED_THEN, "")
    then = f"; {then}" if then else ""
    if isinstance(stop, Terminated):
        sys.stderr.write(f"{prog}: terminated (SIGTERM){then}\n")
        return 143
    sys.stderr.write(f"{prog}: interrupted{then}\n")
    return 130


def _unexpected(args: argparse.Namespace, e: Exception) -> int:
    """Exit 3 for a bug of simreel's, one line; exit 2 where the user's task code raised (`task_code_error`), a
    path given is longer than the file system takes (`_name_too_long`) or the storage refused a write
    (`_storage_refused`)."""
    from simreel.sim.user_code import task_code_error

    user_bug = task_code_error(e) or _name_too_long(e) or _storage_refused(e)
    if user_bug is not None:
        _fail(args, f"error: {user_bug}")
        return 2
    how = "please report it" if args.debug else "rerun with --debug for the traceback, and please report it"
    _fail(args, f"internal error: {type(e).__name__}: {e} ({how})")
    return 3


def _name_too_long(e: Exception) -> str | None:
    """What to say of ENAMETOOLONG, wherever a command first touched the path (None for another error): names simreel
    makes itself are cut to fit (`simreel.io.targets.short_name`) and outputs are checked before any work
    (`check_name_lengths`), so the name is one the user gave, e.g. a recording to read."""
    if not isinstance(e, OSError) or e.errno != errno.ENAMETOOLONG:
        return None
    return f"{e.filename}: a name in this path is longer than the file system takes; give a shorter path"


def _storage_refused(e: Exception) -> str | None:
    """What to say of the storage refusing a write that no writer said in its own words (`storage_error`, which names
    the recording), such as the standard output on a full disk (`> /dev/full`): never simreel's bug. None for
    another error."""
    from simreel.io.durable import is_storage_error, storage_error

    if not is_storage_error(e):
        return None
    return str(storage_error(e.filename or "writing the output", e))  # type: ignore[union-attr]


def _fail(args: argparse.Namespace, message: str) -> None:
    """The one line on stderr for the exception being handled; with --debug its traceback first."""
    if args.debug:
        traceback.print_exc()
    sys.stderr.write(f"simreel {args.command}: {message}\n")


if __name__ == "__main__":
    run()
