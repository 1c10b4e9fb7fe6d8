"""What a replay run has found, in memory that does not grow with the dataset: per-file counts, the worst error per
key, and the episode reports worth printing. `RunTally.summary` is the table `simreel replay` prints;
`RunTally.head` is the report document (`--report`) without its episodes, which `simreel.replay.report.log`
streams after it. `ReplayReport` is one recording's run kept whole, for Python callers (`verify_recording`).
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from simreel.datasets.inputs import shown_path
from simreel.model.components import format_number
from simreel.replay.report.report import CHECK_ORDER, VERDICTS, EpisodeReport, episode_lines

__all__ = ["FileTally", "RunTally", "ReplayReport", "SHOWN_ROWS", "LISTED"]

SHOWN_ROWS = 200
"""A run of at most this many episodes prints a row for each; a larger one only those that did not verify."""
LISTED = 500
"""Episodes that did not verify kept for the summary; the report file lists every one."""


@dataclass
class FileTally:
    """One recording of a run: what it is, how many of its episodes the run replays, and their verdicts so far."""

    path: str
    """Absolute path."""
    env_id: str | None = None
    planned: int = 0
    """Episodes of this file the run replays (all of them, or those --episodes names)."""
    size: int | None = None
    mtime_ns: int | None = None
    error: str | None = None
    """Why the file cannot be replayed at all (unreadable, foreign, no such episode); its episodes are not listed."""
    limits: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    counts: Counter[str] = field(default_factory=Counter)
    steps: int = 0

    @property
    def done(self) -> int:
        return sum(self.counts.values())

    def to_json(self) -> dict[str, Any]:
        return {"path": self.path, "env_id": self.env_id, "size": self.size, "mtime_ns": self.mtime_ns,
                "episodes": self.planned, "error": self.error, "warnings": list(self.warnings),
                "limits": list(self.limits), "counts": {v: self.counts.get(v, 0) for v in VERDICTS},
                "steps": self.steps}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FileTally:
        """A file entry of a report (its counts start at zero: the episodes are counted as they are read)."""
        return cls(path=str(d["path"]), env_id=d.get("env_id"), planned=int(d.get("episodes", 0)),
                   size=d.get("size"), mtime_ns=d.get("mtime_ns"), error=d.get("error"),
                   limits=list(d.get("limits", [])), warnings=list(d.get("warnings", [])))


class RunTally:
    """Everything a run's summary and report need except the episode list, in bounded memory."""

    def __init__(self, mode: str, resync: int | None, tolerances: Mapping[str, float]) -> None:
        self.mode, self.resync, self.tolerances = mode, resync, dict(tolerances)
        self.files: dict[str, FileTally] = {}
        self.rows: list[tuple[str, EpisodeReport]] = []
        """Reports to print: every one while the run is small (`SHOWN_ROWS`), then those that did not verify."""
        self.more = 0
        """Reports that did not verify beyond `LISTED`."""
        self.worst: dict[str, tuple[float, float]] = {}
        """Key → (largest error of any episode, its tolerance)."""
        self.checked: set[str] = set()
        self.notes: list[str] = []
        """What happened on the way (Ray workers that died and whose episodes were replayed again)."""
        self._seen: set[tuple[str, int]] = set()
        self._pruned = False
        self._listed = 0

    def add_file(self, f: FileTally) -> None:
        self.files.setdefault(f.path, f)

    def add(self, path: str, report: EpisodeReport, warnings: Iterable[str] = ()) -> bool:
        """Count `report` of an episode of `path`; False (and nothing counted) when that episode was counted before."""
        if (path, report.index) in self._seen:
            return False
        self._seen.add((path, report.index))
        f = self.files.setdefault(path, FileTally(path))
        f.counts[report.verdict] += 1
        f.steps += report.length
        f.warnings += [w for w in warnings if w not in f.warnings]
        self.checked.update(report.checked)
        for key, err in report.max_abs_error.items():
            if err > self.worst.get(key, (0.0, 0.0))[0]:
                self.worst[key] = (err, report.tolerance.get(key, 0.0))
        self._keep(path, report)
        return True

    def _keep(self, path: str, report: EpisodeReport) -> None:
        if self.total > SHOWN_ROWS and not self._pruned:  # the run outgrew a row per episode
            self.rows = [(p, r) for p, r in self.rows if not r.ok]
            self._pruned = True
        if report.ok and self._pruned:
            return
        if not report.ok and self._listed >= LISTED:
            self.more += 1
            return
        self.rows.append((path, report))
        self._listed += not report.ok

    # ------------------------------------------------------------------ totals
    def count(self, verdict: str) -> int:
        return sum(f.counts.get(verdict, 0) for f in self.files.values())

    @property
    def total(self) -> int:
        """Episodes with a verdict (or an error) so far."""
        return sum(f.done for f in self.files.values())

    @property
    def planned(self) -> int:
        return sum(f.planned for f in self.files.values())

    @property
    def complete(self) -> bool:
        """Every episode the run was to replay has its verdict (or its error)."""
        return all(f.done >= f.planned for f in self.files.values())

    @property
    def unreadable(self) -> list[FileTally]:
        return [f for f in self.files.values() if f.error is not None]

    @property
    def ok(self) -> bool:
        """Every episode verified, none is missing, and every file could be read."""
        return self.complete and not self.unreadable and self.count("diverged") == 0 and self.count("error") == 0

    def exit_status(self) -> int:
        """0 every episode verified; 1 some diverged; 2 some file or episode could not be replayed (bad input), or
        some episode has no verdict (an incomplete run is never a success)."""
        if self.unreadable or self.count("error") or not self.complete:
            return 2
        return 0 if self.count("diverged") == 0 else 1

    def head(self) -> dict[str, Any]:
        """The report document without its ``episodes`` list."""
        totals = {v: self.count(v) for v in VERDICTS}
        totals.update(files=len(self.files), unreadable_files=len(self.unreadable), episodes=self.total,
                      planned=self.planned, steps=sum(f.steps for f in self.files.values()))
        return {"ok": self.ok, "complete": self.complete, "mode": self.mode, "resync": self.resync,
                "tolerances": self.tolerances, "totals": totals, "notes": list(self.notes),
                "files": [f.to_json() for f in self.files.values()]}

    # ------------------------------------------------------------------ summary
    def summary(self, *, top: int = 8) -> str:
        """The readable summary: one file's episode table, or one line per file and the episodes that did not
        verify; the largest errors per key (step and resync modes); what was not checked; the totals."""
        lines = self._file_lines() if len(self.files) == 1 else self._dataset_lines()
        if self.mode == "step" or self.resync:
            lines += self._per_key_table(top)
        lines += self._limit_lines()
        lines += [f"note: {note}" for note in self.notes]
        lines.append(self._verdict_line())
        return "\n".join(lines)

    def _mode(self) -> str:
        return self.mode + (f" --resync {self.resync}" if self.resync else "")

    def _file_lines(self) -> list[str]:
        (f,) = self.files.values()
        if f.error is not None:
            return [f"replay of {shown_path(f.path)}: cannot be replayed: {f.error}"]
        lines = [f"replay of {shown_path(f.path)}: {f.env_id}, mode {self._mode()}, {f.done} episode(s), "
                 f"{f.steps} steps"]
        if self.total > SHOWN_ROWS:
            lines.append(f"episodes that did not verify ({self.total - self.count('exact') - self.count('within_tolerance')}"
                         f" of {self.total}):")
        lines.append(f"  {'episode':>7} {'steps':>6}  {'verdict':<17} first divergence")
        for _, report in sorted(self.rows, key=lambda r: r[1].index):
            lines += episode_lines(report)
        return lines + self._more_line()

    def _dataset_lines(self) -> list[str]:
        ids = {f.env_id for f in self.files.values() if f.env_id}
        steps = sum(f.steps for f in self.files.values())
        lines = [f"replay of {len(self.files)} recordings ({len(ids)} env id(s)), mode {self._mode()}: "
                 f"{self.total} episode(s), {steps} steps"]
        width = max(len(shown_path(p)) for p in self.files)
        lines.append(f"  {'file':<{width}}  {'env id':<28} {'episodes':>8} {'exact':>6} {'within':>6} "
                     f"{'diverged':>8} {'error':>6}")
        for f in self.files.values():
            name = shown_path(f.path)
            if f.error is not None:
                lines.append(f"  {name:<{width}}  cannot be replayed: {f.error}")
                continue
            c = f.counts
            missing = f"  ({f.planned - f.done} not replayed)" if f.done < f.planned else ""
            lines.append(f"  {name:<{width}}  {f.env_id or '?':<28} {f.done:>8} {c['exact']:>6} "
                         f"{c['within_tolerance']:>6} {c['diverged']:>8} {c['error']:>6}{missing}")
        bad = [(p, r) for p, r in self.rows if not r.ok]
        if bad:
            lines.append("episodes that did not verify:")
            for path, report in bad:
                rows = episode_lines(report)
                lines.append(f"  {shown_path(path)}")
                lines += rows
        return lines + self._more_line()

    def _more_line(self) -> list[str]:
        return [f"  ... and {self.more} more that did not verify: see the report (--report)"] if self.more else []

    def _per_key_table(self, top: int) -> list[str]:
        def ratio(k: str) -> float:
            err, tol = self.worst[k]
            return err / tol if tol else math.inf

        keys = sorted((k for k, (err, _) in self.worst.items() if err > 0), key=ratio, reverse=True)
        title = "one-step" if self.mode == "step" else f"resync-{self.resync}"
        lines = [f"largest {title} errors per key (all episodes):"]
        for k in keys[:top]:
            err, tol = self.worst[k]
            lines.append(f"  {k:<55} {format_number(err):>10}  (tolerance {format_number(tol)})")
        if len(keys) > top:
            lines.append(f"  ... {len(keys) - top} more keys differ; see --report")
        if not keys:
            lines.append("  none: every key was reproduced exactly")
        return lines

    def _limit_lines(self) -> list[str]:
        """What was compared, and what not, when some file does not hold everything (ManiSkill's files)."""
        limited = [f for f in self.files.values() if f.limits]
        if not limited:
            return []
        checked = [g for g in CHECK_ORDER if g in self.checked]
        lines = [f"checked at every step: {', '.join(checked) or 'nothing'}"]
        limits: dict[str, int] = {}
        for f in limited:
            for limit in f.limits:
                limits[limit] = limits.get(limit, 0) + 1
        many = len(self.files) > 1
        return lines + [f"limit: {text}" + (f" ({n} of {len(self.files)} files)" if many else "")
                        for text, n in limits.items()]

    def _verdict_line(self) -> str:
        exact, within, diverged, errors = (self.count(v) for v in VERDICTS)
        verified = exact + within
        extra = [f"{errors} could not be replayed"] if errors else []
        # "all verified" only when nothing was left unchecked: an episode that could not be replayed (a corrupt
        # one, say) is not verified
        whole = not errors and not self.unreadable and self.complete
        verdict = f"{diverged} diverged" if diverged else ("all verified" if whole else "none diverged")
        if self.unreadable:
            extra.append(f"{len(self.unreadable)} file(s) unreadable")
        if not self.complete:
            extra.append(f"{self.planned - self.total} not replayed (the run stopped early)")
        return (f"{verified} of {self.total} episode(s) verified ({exact} exact, {within} within tolerance); "
                + "; ".join([verdict, *extra]))


@dataclass
class ReplayReport:
    """Every episode of one recording's replay, kept whole (`verify_recording`)."""

    path: str
    env_id: str
    mode: str
    resync: int | None
    tolerances: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    episodes: list[EpisodeReport] = field(default_factory=list)
    output: str | None = None
    limits: list[str] = field(default_factory=list)
    """What no episode of this recording could check (the file does not hold it: `recording_limits`)."""

    @property
    def ok(self) -> bool:
        return all(e.ok for e in self.episodes)

    def tally(self) -> RunTally:
        tally = RunTally(self.mode, self.resync, self.tolerances)
        tally.add_file(FileTally(os.path.abspath(self.path), self.env_id, len(self.episodes), limits=self.limits,
                                 warnings=list(self.warnings)))
        for e in self.episodes:
            tally.add(os.path.abspath(self.path), e)
        return tally

    def summary(self, *, top: int = 8) -> str:
        """The readable table `simreel replay` prints."""
        return self.tally().summary(top=top)

    def to_json(self) -> dict[str, Any]:
        """The report document `simreel replay --report` writes."""
        doc = self.tally().head()
        doc["output"] = self.output
        path = os.path.abspath(self.path)
        doc["episodes"] = [{"file": path, **e.to_json()} for e in self.episodes]
        return doc
