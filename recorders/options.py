"""`RecordOptions`: what `RecordWrapper` records and how, each option declared once and checked when the options are
made; and the options that differ from the defaults, as ``env.spec`` lists the wrapper (`constructor_options`). Light
to import (no simulator, no gymnasium): ``simreel record`` builds its parser from it."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.options.checks import flag, text, whole_number
from simreel.options.declare import GivenOnce, check_options, documented, option
from simreel.sim.user_code import IMPORTS, import_specs

__all__ = ["RecordOptions", "constructor_options"]


def _contacts(name: str, value: Any) -> str | None:
    from simreel.sim.contacts import contacts_spec  # the live-env side of contacts, kept off the CLI's parser

    return contacts_spec(value)


def _poses(name: str, value: Any) -> bool | None:
    return None if value is None else flag()(name, value)


def _writer_options(name: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise UsageError(f"{name}={value!r}: give a dict of the format's writer options, e.g. "
                         "{\"compression\": \"gzip\"}")
    return value


@documented
@dataclass(frozen=True)
class RecordOptions:
    """What `RecordWrapper` records and how, each option declared once (`simreel.options.declare`): ``simreel
    record``'s flags, their help and the checks of a Python caller's values come from these fields. Each wrong value
    is a `UsageError` when the options are made, not a raw Python error later, nor one taken for another value (a
    flag given as a string), nor one stored where the file could not be read back (a command that is no string)."""

    contacts: str | None = option(
        "auto", action=GivenOnce, metavar="auto|none|A:B,...",
        help="contact channels: auto (default: the net force on every moving body, and the task's or the robot "
             "fingers' pairs), none, or pairs like panda/panda_leftfinger:cube (from Python also a list of \"A:B\" "
             "strings)",
        check=_contacts)
    record_obs: bool = option(False, action="store_true", help="also record observations (T+1 rows per episode)",
                              check=flag())
    poses: bool | None = option(
        None, action=argparse.BooleanOptionalAction, check=_poses,
        help="record world poses of every body and link (needed by MCAP's transform channel; costs about as much per "
             "step as the state dict; default: on for .mcap, off for .h5)")
    overwrite: bool = option(False, action="store_true", help="replace OUT if it exists, instead of refusing",
                             check=flag())
    block_steps: int = option(256, cli=False, help="steps buffered in memory before they are streamed to the file",
                              check=lambda name, value: whole_number(
                                  name, value, "the number of steps to buffer, an int ≥ 1 (default 256)", minimum=1))
    imports: tuple[str, ...] = option(
        default_factory=tuple, spec=IMPORTS, check=lambda name, value: import_specs(value),
        help=IMPORTS.help + ". Stored so replay can import them again (a file by its absolute path); each must be "
                            "found when the recorder starts")
    command: str = option("", cli=False, help="the command line, stored for provenance",
                          check=text("the command line as a string (stored for provenance)"))
    writer_options: Mapping[str, Any] = option(
        default_factory=dict, cli=False, check=_writer_options,
        help="keyword options for the format's writer (HDF5: `compression`; MCAP: `McapOptions`); another name is "
             "refused when the recorder starts, naming those the format takes")
    writer_process: bool = option(
        True, cli=False, check=flag(),
        help="write the file from a child process (`simreel.recorders.writer_process`), so an episode's commit runs "
             "beside the env's reset; `reset()` still returns only once the episodes it ended are committed. False: "
             "write in this process (one process less; each commit then adds to the reset)")

    def __post_init__(self) -> None:
        """Check every option; put contacts in one string (`contacts_spec`), imports in a tuple."""
        check_options(self)


def constructor_options(opts: RecordOptions) -> dict[str, Any]:
    """The options that differ from the defaults, as plain values for ``env.spec`` (gymnasium's WrapperSpec)."""
    default = RecordOptions()
    out = {}
    for f in dataclasses.fields(opts):
        value = getattr(opts, f.name)
        if value != getattr(default, f.name):
            out[f.name] = list(value) if isinstance(value, tuple) else dict(value) if isinstance(value, Mapping) else value
    return out
