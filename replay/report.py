"""The reports of a replay: `EpisodeReport` (one episode's verdict and the numbers behind it) and
`ReplayReport` (every episode of a run, its summary table and its JSON)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from simreel.compare import Divergence, EpisodeComparison, format_number, json_number, worst_keys
from simreel.episode import Episode

__all__ = ["EpisodeReport", "ReplayReport"]


@dataclass
class EpisodeReport:
    """The verdict on one episode's replay."""

    index: int
    seed: int | None
    length: int
    verdict: str
    first_divergence: Divergence | None
    max_abs_error: dict[str, float]
    tolerance: dict[str, float] = field(default_factory=dict)
    diverged_keys: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    """How the replay was done, and what it could not check or reproduce (those also in `limits`)."""
    seconds: float = 0.0
    limits: list[str] = field(default_factory=list)
    """Notes on what was not checked or not reproduced ("contacts not compared: ..."): shown whatever the verdict."""

    @classmethod
    def from_comparison(cls, recorded: Episode, cmp: EpisodeComparison, *, notes: list[str], limits: list[str],
                        seconds: float) -> EpisodeReport:
        """The report of `recorded`'s replay, judged by `cmp`, with the replay's notes and limits."""
        return cls(
            index=recorded.meta.index,
            seed=recorded.meta.seed,
            length=recorded.length,
            verdict=cmp.verdict,
            first_divergence=cmp.first_divergence,
            max_abs_error=cmp.max_abs_error,
            tolerance=cmp.tolerance,
            diverged_keys=cmp.diverged_keys,
            notes=notes,
            limits=limits,
            seconds=seconds,
        )

    @property
    def ok(self) -> bool:
        return self.verdict != "diverged"

    def worst(self, n: int = 3) -> list[tuple[str, float, float]]:
        """Up to n keys that left their tolerance (or came closest), largest error/tolerance first."""
        return worst_keys(self.max_abs_error, self.tolerance, n)

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "seed": self.seed,
            "length": self.length,
            "verdict": self.verdict,
            "first_divergence": None if self.first_divergence is None else self.first_divergence.to_json(),
            "max_abs_error": {k: json_number(v) for k, v in self.max_abs_error.items()},
            "diverged_keys": dict(self.diverged_keys),
            "notes": list(self.notes),
            "limits": list(self.limits),
            "seconds": round(self.seconds, 4),
        }


@dataclass
class ReplayReport:
    """All episodes of one `simreel replay` run."""

    path: str
    env_id: str
    mode: str
    resync: int | None
    tolerances: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    episodes: list[EpisodeReport] = field(default_factory=list)
    output: str | None = None

    @property
    def ok(self) -> bool:
        return all(e.ok for e in self.episodes)

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "path": self.path,
            "env_id": self.env_id,
            "mode": self.mode,
            "resync": self.resync,
            "tolerances": dict(self.tolerances),
            "warnings": list(self.warnings),
            "output": self.output,
            "episodes": [e.to_json() for e in self.episodes],
        }

    def summary(self, *, top: int = 8) -> str:
        """The readable table `simreel replay` prints."""
        mode = self.mode + (f" --resync {self.resync}" if self.resync else "")
        steps = sum(e.length for e in self.episodes)
        lines = [f"replay of {self.path}: {self.env_id}, mode {mode}, {len(self.episodes)} episode(s), {steps} steps"]
        lines.append(f"  {'episode':>7} {'steps':>6}  {'verdict':<17} first divergence")
        for e in self.episodes:
            first = e.first_divergence.describe() if e.first_divergence else ""
            lines.append(f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} {first}".rstrip())
            if not e.ok:
                also = [f"{k} {format_number(v)} (tol {format_number(t)})" for k, v, t in e.worst(4)
                        if e.first_divergence is None or k != e.first_divergence.key]
                if also:
                    n = len(e.diverged_keys)
                    lines.append(f"  {'':>7} {'':>6}  {'':<17} {n} keys left their tolerance; worst: " + ", ".join(also[:3]))
            for note in e.notes if e.verdict != "exact" else e.limits:  # what was not checked: always
                lines.append(f"  {'':>7} {'':>6}  {'':<17} note: {note}")
        if self.mode == "step" or self.resync:
            lines.append(self._per_key_table(top))
        n_exact = sum(e.verdict == "exact" for e in self.episodes)
        n_within = sum(e.verdict == "within_tolerance" for e in self.episodes)
        n_div = len(self.episodes) - n_exact - n_within
        verdict = "all verified" if n_div == 0 else f"{n_div} diverged"
        lines.append(
            f"{len(self.episodes) - n_div} of {len(self.episodes)} episode(s) verified "
            f"({n_exact} exact, {n_within} within tolerance); {verdict}"
        )
        return "\n".join(lines)

    def _per_key_table(self, top: int) -> str:
        worst: dict[str, float] = {}
        tol: dict[str, float] = {}
        for e in self.episodes:
            for k, v in e.max_abs_error.items():
                worst[k] = max(worst.get(k, 0.0), v)
                tol[k] = e.tolerance.get(k, 0.0)
        keys = sorted((k for k in worst if worst[k] > 0), key=lambda k: worst[k] / tol[k] if tol[k] else math.inf,
                      reverse=True)
        title = "one-step" if self.mode == "step" else f"resync-{self.resync}"
        lines = [f"largest {title} errors per key (all episodes):"]
        for k in keys[:top]:
            lines.append(f"  {k:<55} {format_number(worst[k]):>10}  (tolerance {format_number(tol[k])})")
        if len(keys) > top:
            lines.append(f"  ... {len(keys) - top} more keys differ; see --report")
        if not keys:
            lines.append("  none: every key was reproduced exactly")
        return "\n".join(lines)
