"""`RecordOptions`: what `RecordWrapper` records and how, each option checked when the options are made; and the
options that differ from the defaults, as ``env.spec`` lists the wrapper (`constructor_options`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from simreel.errors import UsageError
from simreel.options.checks import check_flag, check_text, whole_number
from simreel.sim.contacts import contacts_spec
from simreel.sim.user_code import import_specs

__all__ = ["RecordOptions", "constructor_options"]


@dataclass(frozen=True)
class RecordOptions:
    """What `RecordWrapper` records and how.

    Attributes:
        contacts: "auto" (net force on every moving body + the task's or the robot fingers' pairs), "none",
            or explicit pairs "panda/panda_leftfinger:cube,..." (or a list of "A:B" strings).
        record_obs: also record observations (T+1 rows per episode).
        poses: also record world poses of every body (needed by MCAP's transform channel; costs about as much
            per step as the state dict). None: the format's default (on for .mcap, off for .h5).
        overwrite: replace an existing file instead of refusing.
        block_steps: steps buffered in memory before they are streamed to the file.
        imports: `--import` specs that registered the task (a .py file or a module name; one string is one spec),
            stored so replay can import them again (a file by its absolute path: `simreel.sim.user_code.found_spec`);
            each must be found when the recorder starts.
        command: the command line, stored for provenance.
        writer_options: keyword options for the format's writer (HDF5: `compression`; MCAP: `McapOptions`); another
            name is refused when the recorder starts, naming those the format takes.
        writer_process: write the file from a child process (`simreel.recorders.writer_process`), so an episode's
            commit runs beside the env's reset; `reset()` still returns only once the episodes it ended are
            committed. False: write in this process (one process less; each commit then adds to the reset).
    """

    contacts: str | None = "auto"
    record_obs: bool = False
    poses: bool | None = None
    overwrite: bool = False
    block_steps: int = 256
    imports: tuple[str, ...] = ()
    command: str = ""
    writer_options: Mapping[str, Any] = field(default_factory=dict)
    writer_process: bool = True

    def __post_init__(self) -> None:
        """Check the options whose wrong type would fail later as a raw Python error, or be taken for another value (a
        flag given as a string), or be stored where the file could not be read back (a command that is not a
        string); put them in one form: contacts as one string (`contacts_spec`), imports as a tuple."""
        object.__setattr__(self, "block_steps", whole_number(
            "block_steps", self.block_steps, "the number of steps to buffer, an int ≥ 1 (default 256)", minimum=1))
        for name in ("record_obs", "overwrite", "writer_process") + (("poses",) if self.poses is not None else ()):
            check_flag(name, getattr(self, name))
        check_text("command", self.command, "the command line as a string (stored for provenance)")
        object.__setattr__(self, "contacts", contacts_spec(self.contacts))
        object.__setattr__(self, "imports", import_specs(self.imports))
        if not isinstance(self.writer_options, Mapping) or not all(isinstance(k, str) for k in self.writer_options):
            raise UsageError(f"writer_options={self.writer_options!r}: give a dict of the format's writer options, "
                             "e.g. {\"compression\": \"gzip\"}")


def constructor_options(opts: RecordOptions) -> dict[str, Any]:
    """The options that differ from the defaults, as plain values for ``env.spec`` (gymnasium's WrapperSpec)."""
    default = RecordOptions()
    out = {}
    for f in dataclasses.fields(opts):
        value = getattr(opts, f.name)
        if value != getattr(default, f.name):
            out[f.name] = list(value) if isinstance(value, tuple) else dict(value) if isinstance(value, Mapping) else value
    return out
