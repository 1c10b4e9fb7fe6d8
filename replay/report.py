"""The reports of a replay: `EpisodeReport` (one episode's verdict and the numbers behind it) and
`ReplayReport` (every episode of a run, its summary table and its JSON)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from simreel.compare import Divergence, EpisodeComparison, format_number, json_number, worst_keys
from simreel.episode import Episode

__all__ = ["EpisodeReport", "ReplayReport", "checked_groups", "recording_limits"]

_CHECK_ORDER = ("env_states", "obs", "contacts", "info", "rewards", "terminated", "truncated", "success", "fail")
_LIMITS = {
    "env_states": "states not compared: the file holds no env_states (recorded without them); the checks are "
                  "the observations, rewards and flags it holds",
    "rewards": "rewards not compared: the file holds none",
    "success": "success not compared: the file holds none",
    "fail": "fail not compared: the file holds none",
    "contacts": "contact forces not compared: the file holds none",
    "info": "info not compared beyond success/fail: the file holds no other info",
    "versions": "versions unknown: the file does not say which ManiSkill and SAPIEN recorded it",
    "sim_config": "sim config unknown beyond the overrides the file gives gym.make",
    "scene_seeds": "scene seeds unknown: each reset is made as the file gives it, on the scene the env holds, as "
                   "ManiSkill's replay_trajectory makes it",
    "reset_options": "reset options unknown: ManiSkill records none for parallel envs; each episode is reset "
                     "with its seed alone",
    "env_idx": "sub-scenes unknown: ManiSkill does not record which parallel env ran an episode; each is "
               "replayed alone (num_envs=1)",
}
"""What a replay cannot check or reproduce when a file does not hold something (`RecordingMeta.unknown`)."""


def recording_limits(unknown: list[str]) -> list[str]:
    """The limits of a replay of a recording that does not hold `unknown`, one line each."""
    return [_LIMITS[u] for u in unknown if u in _LIMITS]


def checked_groups(keys: list[str]) -> list[str]:
    """What a comparison's keys cover, in a fixed order: ``env_states``, ``obs``, ``contacts``, ``info``,
    ``rewards`` and each flag."""
    groups = {k.split("/", 1)[0].split("[", 1)[0] for k in keys}
    return [g for g in _CHECK_ORDER if g in groups]


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
    checked: list[str] = field(default_factory=list)
    """What was compared at every step (`checked_groups`)."""

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
            checked=checked_groups(list(cmp.errors)),
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
            "checked": list(self.checked),
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
    limits: list[str] = field(default_factory=list)
    """What no episode of this recording could check (the file does not hold it: `recording_limits`)."""

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
            "limits": list(self.limits),
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
            lines += _episode_lines(e)
        if self.mode == "step" or self.resync:
            lines.append(self._per_key_table(top))
        if self.limits:  # a file that does not hold everything: say what was checked, and what not
            checked = [g for g in _CHECK_ORDER if any(g in e.checked for e in self.episodes)]
            lines.append(f"checked at every step: {', '.join(checked) or 'nothing'}")
            lines += [f"limit: {limit}" for limit in self.limits]
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


def _episode_lines(e: EpisodeReport) -> list[str]:
    """An episode's row of the summary table, its worst keys when it diverged, and its notes."""
    pad = f"  {'':>7} {'':>6}  {'':<17}"
    first = e.first_divergence.describe() if e.first_divergence else ""
    lines = [f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} {first}".rstrip()]
    if not e.ok:
        also = [f"{k} {format_number(v)} (tol {format_number(t)})" for k, v, t in e.worst(4)
                if e.first_divergence is None or k != e.first_divergence.key]
        if also:
            lines.append(f"{pad} {len(e.diverged_keys)} keys left their tolerance; worst: " + ", ".join(also[:3]))
    lines += [f"{pad} note: {note}" for note in (e.notes if e.verdict != "exact" else e.limits)]  # always: unchecked
    return lines
