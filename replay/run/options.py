"""`ReplayOptions`: how a replay run replays and judges recordings — what `simreel replay` takes, each option declared
once (`simreel.options.declare`): the command's flags, their help, the Python checks and the list of options that
decide the verdicts all come from these fields. Light to import: ``simreel replay --help`` builds its parser from it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.model.components import Tolerances
from simreel.model.selection import EpisodeSelection, parse_index_ranges
from simreel.options.checks import flag, mapping, path, text, whole
from simreel.options.declare import GivenOnce, check_options, documented, names_tagged, option
from simreel.options.parallel import RAY, WORKERS, check_workers
from simreel.sim.user_code import IMPORTS, TRUST_IMPORTS
from simreel.verdicts.options import ATOL, TOL, mode_choices

__all__ = ["ReplayOptions", "MODES", "VERDICT_OPTIONS", "json_value"]

MODES = tuple(mode_choices())
"""The replay modes: actions, states, step; ``resync`` is an option of ``actions`` (with its own default tolerances,
see `simreel.model.components.TOLERANCE_MODES`)."""


@documented
@dataclass(frozen=True)
class ReplayOptions:
    """How a `ReplayRun` replays and judges recordings: what `simreel replay` takes, each option declared once here
    (`simreel.options.declare`): the command's flags, their help and their checks come from these fields. Options
    tagged ``verdict`` decide the verdicts (a report keeps them; a resumed run uses them); those tagged ``execution``
    only say how the work is spread, and may change when a run is resumed."""

    mode: str = option("actions", flags=("--mode",), choices=mode_choices, tags=["verdict"],
                       help="actions: step the recorded actions from the reproduced reset (default); "
                            "states: restore every recorded state and recompute reward/info/obs; "
                            "step: restore state t, step action t, compare with state t+1 (one-step error)")
    resync: int | None = option(None, metavar="K", parse=int, tags=["verdict"],
                                help="with --mode actions: restore the recorded state every K steps",
                                check=whole("the number of actions between two restores of the recorded state, an "
                                            "int >= 1, or None (never restore)", optional=True))
    episodes: EpisodeSelection | Sequence[int] | None = option(
        None, metavar="LIST", action=GivenOnce, tags=["verdict"],
        from_cli=lambda text: None if text is None else parse_index_ranges(text),
        help="episodes to replay of every recording, e.g. 0,3-7 (default: all)",
        check=lambda name, value: EpisodeSelection.of(value))  # ranges; a report keeps the text, which `of` reads
    atol: float | None = option(None, spec=ATOL, tags=["verdict"])
    group_tolerances: Mapping[str, float] = option(
        default_factory=dict, spec=TOL, tags=["verdict"],
        check=mapping('a dict of tolerance groups and numbers, e.g. {"contact": 5.0}'))
    output: str | None = option(None, flags=("-o", "--output"), metavar="REPLAYED",
                                help="write the replayed episodes of one recording (.h5/.mcap)",
                                check=path("the file to write the replayed episodes to, a str or pathlib.Path ending "
                                           "in .h5 or .mcap, or None"))
    overwrite: bool = option(False, action="store_true", check=flag(),
                             help="replace the -o and --report files if they exist")
    obs_mode: str | None = option(None, tags=["verdict"],
                                  help="observation mode of the replay (e.g. rgb with --mode states -o OUT to "
                                       "re-render)",
                                  check=text('an observation mode as a string, e.g. "rgb", or None (the recorded '
                                             "one)", optional=True))
    workers: int = option(1, spec=WORKERS, tags=["execution"])
    imports: tuple[str, ...] = option(default_factory=tuple, spec=IMPORTS, tags=["verdict"])
    trust_recorded_imports: bool = option(False, spec=TRUST_IMPORTS, tags=["execution"])
    sim_backend: str | None = option(None, tags=["verdict"],
                                     help="replay on another sim backend than the recorded one (physx_cpu, "
                                          "physx_cuda); a GPU recording on a machine without CUDA: physx_cpu "
                                          "(another engine, so the verdict is not exact)",
                                     check=text('a sim backend as a string, e.g. "physx_cpu", or None (the recorded '
                                                "one)", optional=True))
    command: str = option("", cli=False, help="the command line, kept in the output's metadata",
                          check=text("the command line as a string (kept in the output's metadata)"))
    report: str | None = option(None, metavar="REPORT.json",
                                help="stream every verdict into REPORT.jsonl as it comes and write the report "
                                     "REPORT.json",
                                check=path("the report to write, a str or pathlib.Path (REPORT.json), or None"))
    resume: bool = option(False, cli=False, check=flag(),
                          help="continue `report`: replay only the episodes it has no verdict for, with the options "
                               "it was made with (the command line's --resume REPORT.json)")
    ray: str | None = option(None, spec=RAY, tags=["execution"])
    ship: bool = option(False, action="store_true", tags=["execution"], check=flag(),
                        help="with --ray: send every episode from this machine to the workers (by default they read "
                             "the recordings they see as this machine does, on a shared filesystem, and get the rest "
                             "sent)")

    def __post_init__(self) -> None:
        """Check every option (`check_options`), so that a wrong one is a `UsageError` here, naming it and what to
        give, not a raw error once the run starts or a value taken for another (``resync=True`` as 1,
        ``overwrite="no"`` as yes); then the rules between them (`tolerances`), and the tolerances as floats."""
        check_options(self)
        self.tolerances()  # the values: mode, resync, workers, tolerances
        object.__setattr__(self, "group_tolerances", {g: float(t) for g, t in self.group_tolerances.items()})
        if self.atol is not None:
            object.__setattr__(self, "atol", float(self.atol))

    def tolerances(self) -> Tolerances:
        """The tolerances these options ask for; `UsageError` for a bad mode, resync, worker count or tolerance."""
        if self.mode not in MODES:
            raise UsageError(f"unknown --mode {self.mode!r}; expected one of {', '.join(MODES)}")
        if self.resync is not None and self.mode != "actions":
            raise UsageError(f"--resync works with --mode actions only (got --mode {self.mode})")
        if self.resync is not None and self.resync < 1:
            raise UsageError(f"--resync must be >= 1, got {self.resync}")
        check_workers(self.workers)
        if self.resume and self.report is None:
            raise UsageError("resume needs the report to continue (--resume REPORT.json)")
        if self.ship and self.ray is None:  # it only tells Ray actors what to read
            raise UsageError("--ship works with --ray only: it sends the episodes to the Ray actors")
        try:  # the tolerances' own rule (`simreel.model.components`): finite numbers >= 0, groups it knows
            return Tolerances.for_mode("resync" if self.resync else self.mode, atol=self.atol,
                                       groups=self.group_tolerances)
        except ValueError as e:
            raise UsageError(str(e)) from None

    def verdict_options(self) -> dict[str, Any]:
        """The options that decide the verdicts, as a report's run line keeps them (a resumed run uses them)."""
        return {name: json_value(getattr(self, name)) for name in VERDICT_OPTIONS}


VERDICT_OPTIONS = names_tagged(ReplayOptions, "verdict")
"""The options that decide a replay's verdicts."""


def json_value(value: Any) -> Any:
    """An option's value as a report's run line keeps it: episodes as their text, tuples as lists."""
    if isinstance(value, EpisodeSelection):
        return value.to_json()
    return list(value) if isinstance(value, tuple) else value
