"""What a conversion reports: every episode's verdict, whether it was written, and the check of the written file
(`ConversionReport`, with the table `simreel convert` prints), and what it says it checked (`checked_text`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from simreel.model.components import format_number
from simreel.replay.report.report import CHECK_ORDER, EpisodeReport, episode_lines

__all__ = ["ConversionReport", "checked_text", "describe"]


@dataclass
class ConversionReport:
    """Every episode of one conversion: its verdict, whether it was written, and the check of the written file."""

    path: str
    output: str
    env_id: str
    conversion: dict[str, Any]
    tolerances: dict[str, float]
    episodes: list[EpisodeReport] = field(default_factory=list)
    written: list[int] = field(default_factory=list)
    dropped: dict[int, str] = field(default_factory=dict)
    """Episode -> why a `keep` filter left it out."""
    written_check: str = ""
    written_mismatch: list[int] = field(default_factory=list)
    """Written episodes whose states or actions read back from the output differ from what they must be."""
    warnings: list[str] = field(default_factory=list)
    limits: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every converted episode verified (written or left out), something written, and the written file
        checked."""
        return bool(self.written) and all(e.ok for e in self.episodes) and not self.written_mismatch

    def to_json(self) -> dict[str, Any]:
        return {"ok": self.ok, "path": self.path, "output": self.output, "env_id": self.env_id,
                "conversion": self.conversion, "tolerances": self.tolerances, "warnings": self.warnings,
                "limits": self.limits, "written": self.written, "left_out": len(self.dropped), "dropped": {str(k): v for k, v in self.dropped.items()},
                "written_check": self.written_check, "written_mismatch": self.written_mismatch,
                "episodes": [e.to_json() for e in self.episodes]}

    def summary(self) -> str:
        """The table `simreel convert` prints."""
        steps = sum(e.length for e in self.episodes)
        tracked = bool(self.conversion.get("control_mode"))
        lines = [f"conversion of {self.path} -> {self.output}: {self.env_id}, {describe(self.conversion)}, "
                 f"{len(self.episodes)} episode(s), {steps} steps"]
        if tracked:
            lines.append("  largest error per episode: commanded and reached tool-centre pose (m, rad), objects (m, "
                         "rad), success timing (steps); tolerances "
                         + ", ".join(f"{k} {format_number(v)}" for k, v in self.tolerances.items()))
        head = f"  {'episode':>7} {'steps':>6}  {'verdict':<17}"
        columns = ("cmd m", "cmd rad", "ee m", "ee rad", "obj m", "obj rad")
        lines.append(head + ("".join(f" {c:>8}" for c in columns) + f" {'succ':>4}" if tracked else "")
                     + " first step out of tolerance")
        for e in self.episodes:
            rows = episode_lines(e)
            if tracked:
                rows[0] = _tracked_row(e)
            lines += rows
            if e.index in self.dropped:
                lines.append(f"  {'':>7} {'':>6}  {'':<17} not written: {self.dropped[e.index]}")
        lines += [f"limit: {limit}" for limit in self.limits]
        lines.append(f"checked: {self.conversion['checked']}")
        if self.written_check:
            lines.append(f"written: {self.written_check}")
        n_ok = sum(e.ok and e.index not in self.written_mismatch for e in self.episodes)
        lines.append(f"{n_ok} of {len(self.episodes)} episode(s) verified; {len(self.written)} written to {self.output}"
                     + self._left_out_text())
        return "\n".join(lines)

    def _left_out_text(self) -> str:
        """``; 3 left out (2 not verified, 1 no success at its last step)``: how many `keep` left out, and why."""
        if not self.dropped:
            return ""
        why = Counter(reason.split(" (")[0] for reason in self.dropped.values())
        hint = "; --keep all writes them" if "not verified" in why else ""
        return (f"; {len(self.dropped)} left out by --keep ({', '.join(f'{n} {w}' for w, n in why.items())}"
                f"{hint})")


def describe(conversion: Mapping[str, Any]) -> str:
    """``obs none -> rgb, control pd_joint_pos -> pd_ee_delta_pose``."""
    parts = [f"{what.split('_')[0]} {pair[0]} -> {pair[1]}" for what in ("obs_mode", "control_mode")
             if (pair := conversion.get(what))]
    return ", ".join(parts)


def _tracked_row(e: EpisodeReport) -> str:
    """An episode's row with its largest tracking error per group."""
    def worst(prefix: str, suffix: str) -> str:
        values = [v for k, v in e.max_abs_error.items() if k.startswith(prefix) and k.endswith(suffix)]
        return format_number(max(values)) if values else "-"

    success = e.max_abs_error.get("success")
    cells = [worst("command/", "[p]"), worst("command/", "[q]"), worst("ee/", "[p]"), worst("ee/", "[q]"),
             worst("env_states/", "p]"), worst("env_states/", "q]")]
    first = e.first_divergence.describe() if e.first_divergence else ""
    return (f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} " + " ".join(f"{c:>8}" for c in cells)
            + f" {'-' if success is None else format_number(success):>4} {first}").rstrip()


_RENDER_CHECKS = {"env_states": "each restored state read back within the 'states' tolerances",
                  "obs": "the rendered observations against the recorded ones",
                  "contacts": "recorded contact forces against one step simulated from the state",
                  "info": "recorded info", "rewards": "recomputed rewards"}
"""What a re-render compares of each group (`CHECK_ORDER`; the flags, `_FLAGS`, as one) when the file holds it."""
_FLAGS = ("terminated", "truncated", "success", "fail")


def checked_text(unknown: list[str], *, tracked: bool, obs: bool) -> str:
    """What a conversion compares per step of a file that does not hold `unknown` (`RecordingMeta.unknown`, which
    also gives the limits lines): a re-render what a replay in mode 'states' compares of what the file holds (its
    observations where `obs`, `compares_obs`), a control-mode conversion the tracking groups (success timing when
    the file holds success)."""
    if tracked:
        groups = ["commanded and reached tool-centre pose", "object poses", "success timing"]
        groups = groups if "success" not in unknown else groups[:-1]
        return "per step, the converted run against the recorded one: " + ", ".join(groups)
    held = [g for g in CHECK_ORDER if (g != "obs" or obs) and g not in unknown]
    flags = [g for g in held if g in _FLAGS]
    parts = [_RENDER_CHECKS[g] for g in held if g not in _FLAGS] + [f"recomputed flags ({', '.join(flags)})"]
    return "per step, " + ", ".join(parts) + "; the output's states and actions equal the input's"
