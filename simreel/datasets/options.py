"""The options of the dataset operations (`simreel.datasets.dataset`), each declared once (`simreel.options.declare`):
`DatasetOptions`, how `merge` and `filter_recording` write, and `EpisodeCriteria`, which episodes a filter keeps.
Light to import (no format, no h5py): ``simreel merge`` and ``simreel filter`` build their parsers from them."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any, TypeVar

from simreel.errors import UsageError
from simreel.model.meta import EpisodeMeta
from simreel.model.selection import EpisodeSelection, parse_index_ranges
from simreel.options.checks import check_callable, check_text, flag, is_whole_number, text, whole_number
from simreel.options.declare import GivenOnce, check_options, documented, option
from simreel.verdicts.report_file import REPORT_VERDICTS

__all__ = ["DatasetOptions", "EpisodeCriteria", "Progress", "no_success_note", "uncovered_note"]

_T = TypeVar("_T")
Progress = Callable[[Sequence[_T], str], Iterable[_T]]
"""`progress(items, what)` wraps a list of work items ("merge", "filter", "check ...") in a progress bar."""


def _no_bar(items: Sequence[_T], what: str) -> Iterable[_T]:
    return items


def _progress(name: str, value: Any) -> Progress:
    check_callable(name, value, "a function called as progress(items, what) that returns the items (a progress bar), "
                   "or leave it out")
    return value or _no_bar


@documented
@dataclass(frozen=True)
class DatasetOptions:
    """How `merge` and `filter_recording` write, each option declared once (`simreel.options.declare`): what
    ``simreel merge`` and ``simreel filter`` take besides their files. A value of the wrong type is a `UsageError`
    naming it and what to give, before any file is read or written: ``overwrite="no"`` would count as yes and replace
    OUT, a command that is no string fail only once the output is being written."""

    overwrite: bool = option(False, action="store_true", check=flag(),
                             help="replace the outputs (OUT, and OTHER of filter --rest) and their side files if they "
                                  "exist, instead of refusing")
    command: str = option("", cli=False, help="the command line, stored in the outputs' metadata",
                          check=text("the command line as a string (stored in the outputs' metadata)"))
    progress: Progress = option(_no_bar, cli=False, check=_progress,
                                help="wraps each pass's work list (a progress bar); see `Progress`. None: none")

    def __post_init__(self) -> None:
        check_options(self)


def _success(name: str, value: Any) -> bool | None:
    return None if value is None else bool(flag()(name, value))  # compared with `is`: np.False_ is not False


def _steps(name: str, value: Any) -> int | None:
    if value is None:
        return None
    value = whole_number(name, value, "a number of steps, an int >= 0, or None (no bound)")
    if value < 0:
        raise UsageError(f"--{name.replace('_', '-')} must be >= 0, got {value}")
    return value


@documented
@dataclass(frozen=True)
class EpisodeCriteria:
    """Which episodes `filter_recording` keeps: those that meet every criterion given (None: not a criterion), each
    declared once (`simreel.options.declare`): ``simreel filter``'s criteria flags come from these fields, and a
    criterion of the wrong type is a `UsageError` naming it and what to give, not a raw error once the file is read
    nor one taken for another (``success="no"`` or ``success=0``, which no final success ``is``, keeping nothing;
    ``min_steps=True`` as 1; ``keep_verdicts`` without `verdicts` ignored)."""

    episodes: EpisodeSelection | Sequence[int] | None = option(
        None, metavar="LIST", action=GivenOnce, from_cli=lambda text: None if text is None else parse_index_ranges(text),
        help="original episode indices, e.g. 0,3-7 (from Python an `EpisodeSelection` or indices)",
        check=lambda name, value: EpisodeSelection.of(value))  # ranges, whatever the numbers
    success: bool | None = option(
        None, check=_success, help="episodes whose final success is true (a file without success has none)",
        negative="episodes whose final success is false")
    min_steps: int | None = option(None, metavar="N", parse=int, check=_steps, help="episodes of at least N steps")
    max_steps: int | None = option(None, metavar="N", parse=int, check=_steps, help="episodes of at most N steps")
    verdicts: Mapping[int, str] | None = option(
        None, cli=False, help="a replay's verdict of each episode of the file (index → ``exact``, ``within_tolerance``, "
                              "``diverged``, ``error``); an episode it does not cover meets no verdict criterion "
                              "(``simreel filter --verified/--diverged REPORT``)")
    keep_verdicts: tuple[str, ...] = option((), cli=False, help="the verdicts to keep (with `verdicts`)")
    report: str = option("", cli=False, help="where `verdicts` came from, for the provenance")

    def __post_init__(self) -> None:
        """Check every criterion (`check_options`), then those given together: the bounds, and the verdicts with
        those to keep; put them in one form: episodes as an `EpisodeSelection`, counts as ints, verdicts as a dict and
        the verdicts to keep as a tuple."""
        check_options(self)
        if self.min_steps is not None and self.max_steps is not None and self.min_steps > self.max_steps:
            raise UsageError(f"--min-steps {self.min_steps} is above --max-steps {self.max_steps}: no episode fits")
        self._check_verdicts()

    def _check_verdicts(self) -> None:
        """The verdict criterion: `verdicts` a mapping of episode indices to verdicts, `keep_verdicts` one or more of
        `REPORT_VERDICTS` (one string is one verdict, not its characters), each given with the other, `report`
        a string."""
        keep = (self.keep_verdicts,) if isinstance(self.keep_verdicts, str) else self.keep_verdicts
        names = ", ".join(REPORT_VERDICTS)
        if not isinstance(keep, (list, tuple)) or not all(v in REPORT_VERDICTS for v in keep):
            raise UsageError(f"keep_verdicts={self.keep_verdicts!r}: give the verdicts to keep as a tuple of any of "
                             f"{names}, e.g. (\"exact\", \"within_tolerance\")")
        object.__setattr__(self, "keep_verdicts", tuple(keep))
        verdicts = self.verdicts
        if verdicts is not None:
            if not isinstance(verdicts, Mapping) or not all(is_whole_number(i) and isinstance(v, str)
                                                            for i, v in verdicts.items()):
                raise UsageError(f"verdicts={verdicts!r}: give a replay's verdict of each episode as a dict of "
                                 f"episode indices and verdicts ({names}), e.g. {{0: \"exact\"}} "
                                 "(simreel.datasets.dataset.report_verdicts reads them from a replay report)")
            object.__setattr__(self, "verdicts", {int(i): v for i, v in verdicts.items()})
        if (verdicts is None) != (not self.keep_verdicts):
            given, missing = ("verdicts", "keep_verdicts") if verdicts is not None else ("keep_verdicts", "verdicts")
            raise UsageError(f"{given} without {missing}: give both (the verdicts of the file's episodes, and those to "
                             "keep), or neither")
        check_text("report", self.report, "where the verdicts came from as a string (the replay report's path)")

    def given(self) -> bool:
        return any(v is not None for v in (self.episodes, self.success, self.min_steps, self.max_steps,
                                           self.verdicts))

    def keeps(self, meta: EpisodeMeta) -> bool:
        """Whether the episode of `meta` meets every criterion."""
        return all(meets(meta) for _, meets in self._each())

    def _each(self) -> list[tuple[str, Callable[[EpisodeMeta], bool]]]:
        """Each criterion given: what it is, for people (``episodes 0,3,4``, ``success``, ``>= 20 steps``), and
        whether an episode's metadata meets it."""
        parts: list[tuple[str, Callable[[EpisodeMeta], bool]]] = []
        if self.episodes is not None:
            first = list(islice(self.episodes, 11))  # a range is walked no further than shown
            shown = ",".join(str(i) for i in first[:10])
            parts.append((f"episodes {shown}{',...' if len(first) > 10 else ''}",
                          lambda m: m.index in self.episodes))
        if self.success is not None:
            parts.append(("success" if self.success else "no success", lambda m: m.success is self.success))
        if self.min_steps is not None:
            parts.append((f">= {self.min_steps} steps", lambda m: m.length >= self.min_steps))
        if self.max_steps is not None:
            parts.append((f"<= {self.max_steps} steps", lambda m: m.length <= self.max_steps))
        if self.verdicts is not None:
            parts.append((f"{' or '.join(self.keep_verdicts)} in {Path(self.report).name}",
                          lambda m: self.verdicts.get(m.index) in self.keep_verdicts))
        return parts

    def describe(self) -> str:
        """The criteria given, for people: ``episodes 0,3,4; success; >= 20 steps``."""
        return "; ".join(what for what, _ in self._each())

    def why_none(self, episodes: Sequence[EpisodeMeta]) -> str:
        """Why none of `episodes` is kept, for people: how many meet each criterion alone, and how many hold no
        final success (with a success criterion) or lack a verdict (with a verdict one)."""
        if not episodes:
            return "the file holds no episode"
        met = [f"{sum(1 for m in episodes if meets(m))} meet {what}" for what, meets in self._each()]
        why = f"of {len(episodes)} episode(s): {', '.join(met)}{', none all' if len(met) > 1 else ''}"
        no_success, uncovered = self.no_success(episodes), self.uncovered(episodes)
        why += f"; {no_success_note(no_success)}" if no_success else ""
        return why + (f"; {uncovered_note(uncovered)}" if uncovered else "")

    def no_success(self, episodes: Sequence[EpisodeMeta]) -> int:
        """With a success criterion, how many of `episodes` hold no final success (0 without one)."""
        return sum(1 for m in episodes if m.success is None) if self.success is not None else 0

    def uncovered(self, episodes: Sequence[EpisodeMeta]) -> int:
        """With a verdict criterion, how many of `episodes` its report does not cover (0 without one)."""
        return sum(1 for m in episodes if m.index not in self.verdicts) if self.verdicts is not None else 0

    def to_json(self) -> dict[str, Any]:
        """The criteria given, for the provenance (the verdicts as the report's path and the verdicts kept)."""
        d: dict[str, Any] = {k: getattr(self, k) for k in ("episodes", "success", "min_steps", "max_steps")
                             if getattr(self, k) is not None}
        if "episodes" in d:  # as many as the file has at most: `filter_recording` refused any it lacks
            d["episodes"] = list(d["episodes"])
        if self.verdicts is not None:
            d.update(report=self.report, verdicts=list(self.keep_verdicts))
        return d


def no_success_note(count: int) -> str:
    return f"{count} episode(s) hold no final success: neither --success nor --no-success keeps them"


def uncovered_note(count: int) -> str:
    return f"{count} episode(s) are not in the replay report: not kept"
