"""Options shared by every command that builds an env, and the helpers that apply them."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.model.selection import parse_index_ranges
from simreel.options.checks import parse_json_kwargs, parse_size
from simreel.options.declare import GivenOnce, Option, add_arguments, add_option, check_options, option
from simreel.sim.user_code import IMPORTS, TRUST_IMPORTS
from simreel.verdicts.options import ATOL, TOL, mode_choices, parse_group_tolerance, parse_tolerance

__all__ = ["EnvOptions", "QUIET", "add_env_options", "env_options", "add_import_option", "apply_imports", "parse_json_kwargs", "parse_index_ranges",
           "parse_size", "add_tolerance_options", "parse_tolerance", "parse_group_tolerance", "progress_bar", "mode_choices",
           "GivenOnce", "LOG_LINE_SECONDS", "STOPPED_THEN", "stopped_saying", "write_json_report"]


STOPPED_THEN = "simreel_then"
"""The attribute of a Ctrl-C/SIGTERM (`KeyboardInterrupt`) that holds what the stopped command kept and how to
finish, which its one line ends with (`stopped_saying`)."""


def stopped_saying(stop: KeyboardInterrupt, then: str) -> None:
    """Make the one line of the command `stop` stops ("interrupted", "terminated (SIGTERM)") go on with `then`."""
    setattr(stop, STOPPED_THEN, then)


def write_json_report(path: str, doc: Any, *, kept: str, again: str) -> None:
    """Write the JSON document `doc` to `path` (whole or not at all: `write_text_atomic`). A write the storage
    refuses (a full disk) is one line naming `path`, saying what the command wrote and kept (`kept`) and how to
    have the report (`again`)."""
    import json
    from pathlib import Path

    from simreel.errors import StorageError
    from simreel.io.durable import is_storage_error, storage_error
    from simreel.io.targets import write_text_atomic

    try:
        write_text_atomic(path, json.dumps(doc, indent=2) + "\n")
    except OSError as e:
        if not is_storage_error(e):
            raise
        error = storage_error(Path(path), e)
        raise StorageError(path, error.reason, f"{error.fix}, then {again}", f": the report was not written; {kept}") \
            from None


LOG_LINE_SECONDS = 60.0
"""Off a terminal, a progress bar is a plain line on stderr this often, the first once the work has run this long."""


def progress_bar(items: Iterable[Any] | None = None, *, quiet: bool, **options: Any) -> Any:
    """A tqdm bar on stderr, never with -q. On a terminal it redraws in place; elsewhere (a log file, CI, a pipe) it
    is a plain line every `LOG_LINE_SECONDS`, the first once the work has run that long: a long batch job shows it
    is alive and how far it got, and a short run's stderr is only what the command says."""
    from tqdm import tqdm

    if quiet:
        return tqdm(items, disable=True, **options)
    if sys.stderr.isatty():
        return tqdm(items, file=sys.stderr, **options)
    lines = _LogLines(sys.stderr)
    bar = tqdm(items, file=lines, ascii=True, delay=LOG_LINE_SECONDS, mininterval=LOG_LINE_SECONDS, miniters=1,
               **options)
    lines.bar = bar
    return bar


class _LogLines:
    """Where a progress bar draws off a terminal: each redraw (tqdm begins it with a carriage return and pads it with
    spaces) becomes a line of its own, but for the one closing the bar where it repeats the last count."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self.bar: Any = None
        """The bar drawing here (its count tells a new line from the closing one); None while it is made."""
        self._count: float | None = None
        """The count of the last line written."""

    def write(self, text: str) -> None:
        count = None if self.bar is None else self.bar.n
        for line in text.replace("\r", "\n").split("\n"):
            if line.strip() and (count is None or count != self._count):
                self._stream.write(line.rstrip() + "\n")
                self._count = count

    def flush(self) -> None:
        self._stream.flush()


def add_import_option(p: argparse.ArgumentParser, *, reads_recordings: bool = False) -> None:
    """``--import``; with `reads_recordings` (a command that rebuilds a recording's env) ``--trust-recorded-imports``
    too."""
    add_option(p, "imports", IMPORTS, [])
    if reads_recordings:
        add_option(p, "trust_recorded_imports", TRUST_IMPORTS, False)


QUIET = Option(help="no progress bar", flags=("-q", "--quiet"), action="store_true")
"""``-q``, declared once for the commands that show a progress bar and take it."""


def _num_envs(name: str, value: int | None) -> int | None:
    if value is not None and value < 1:
        raise UsageError(f"--num-envs must be ≥ 1, got {value}")
    return value


@dataclass(frozen=True)
class EnvOptions:
    """The env's gym.make options of a command that builds one (`add_env_options`); each not given stays None, its
    default `simreel.sim.make.EnvConfig`'s (`env_options`)."""

    obs_mode: str | None = option(None, help="ManiSkill obs_mode (default: state)")
    control_mode: str | None = option(None, help="ManiSkill control_mode (default: the task's)")
    reward_mode: str | None = option(None, help="ManiSkill reward_mode (default: the task's)")
    sim_backend: str | None = option(None, help="physx_cpu, physx_cuda or auto (default)")
    render_backend: str | None = option(None, help="gpu, cpu, none or auto (default: detected)")
    num_envs: int | None = option(None, parse=int, check=_num_envs,
                                  help="parallel envs (>1 needs the GPU sim; default: 1)")
    env_kwargs: dict[str, Any] = option(default_factory=dict, parse=parse_json_kwargs, metavar="JSON",
                                        help='extra gym.make kwargs as a JSON object, e.g. \'{"robot_uids": "panda"}\'')

    def __post_init__(self) -> None:
        check_options(self)


def add_env_options(p: argparse.ArgumentParser) -> None:
    """The env's gym.make options (`EnvOptions`)."""
    add_arguments(p, EnvOptions)


_ENV_OPTIONS = ("obs_mode", "control_mode", "reward_mode", "sim_backend", "render_backend", "num_envs")
"""The `EnvConfig` fields `EnvOptions` gives options for (besides `env_kwargs`)."""


def env_options(env_id: str, options: EnvOptions) -> dict[str, Any]:
    """The env options given, as `EnvConfig` arguments; `EnvBuildError` where --env-kwargs gives one of them too,
    otherwise (``--obs-mode state --env-kwargs '{"obs_mode": "rgb"}'``), even at its default value, which
    `EnvConfig` alone cannot tell from one not given."""
    from simreel.sim.make import refuse_repeated

    given = {name: getattr(options, name) for name in _ENV_OPTIONS if getattr(options, name) is not None}
    refuse_repeated(env_id, given, options.env_kwargs)
    return given


def apply_imports(specs: list[str]) -> None:
    from simreel.sim.user_code import import_user_code

    for spec in specs:
        import_user_code(spec)


def refuse_tolerances_without_compare(args: argparse.Namespace) -> None:
    """`UsageError` for tolerance options (`add_tolerance_options`: --mode, --atol, --tol; those the command has) given
    without --compare: they judge a --compare file against the recording, so without one they would be ignored."""
    given = [name for name, value in (("--mode", getattr(args, "mode", None)), ("--atol", getattr(args, "atol", None)),
                                      ("--tol", getattr(args, "tol", None) or None)) if value is not None]
    if given and args.compare is None:
        names = ", ".join(given)
        raise UsageError(f"{names}: tolerances judge a --compare file against the recording, and none was given; add "
                         f"--compare OTHER, or leave {names} out")


def add_tolerance_options(p: argparse.ArgumentParser, *, mode_help: str, mode_default: str | None = "actions") -> None:
    """`--mode` (a replay mode: whose default tolerances apply; `mode_default` when not given), `--atol X` and
    `--tol GROUP=X` (repeatable), as `simreel.verdicts.options` declares them."""
    p.add_argument("--mode", choices=mode_choices(), default=mode_default, help=mode_help)
    add_option(p, "atol", ATOL, None)
    add_option(p, "tol", TOL, [])
