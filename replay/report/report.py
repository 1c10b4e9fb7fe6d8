"""One episode's verdict and the numbers behind it (`EpisodeReport`), as a run's summary prints it and its report
file holds it; and what a recording cannot let a replay check (`recording_limits`). A run's totals and summary
are `simreel.replay.report.tally`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from simreel.formats.base import EpisodeRows
from simreel.model.components import format_number, json_number
from simreel.model.episode import Episode
from simreel.model.fields import FLAG_FIELDS
from simreel.model.lineage import EpisodeVerification
from simreel.model.meta import RecordingMeta
from simreel.sim.fingerprint import SceneDifference
from simreel.verdicts.compare import Divergence, EpisodeComparison, worst_keys
from simreel.verdicts.divergence import Explanation
from simreel.verdicts.report_file import REPORT_VERDICTS, VERIFIED

__all__ = ["EpisodeReport", "HistoryEntry", "VERIFIED", "VERDICTS", "CHECK_ORDER", "WITH_ENV_STATES", "checked_groups", "recording_limits",
           "only_flags_problem", "episode_lines"]

VERDICTS = REPORT_VERDICTS
"""Every verdict an episode can have: verified (`VERIFIED`), ``diverged``, or ``error`` (it could not be replayed:
its data is damaged, or its env does not build here)."""
CHECK_ORDER = ("env_states", "obs", "contacts", "info", "rewards", "terminated", "truncated", "success", "fail")
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


WITH_ENV_STATES = ("record with them (RecordEpisode(record_env_state=True), simreel record), or let ManiSkill's "
                   "replay_trajectory --save-traj write a copy that has them")
"""How to come by a recording with env states, for the commands that need them."""
_FLAG_REWARD_MODES = ("sparse", "none")
"""Reward modes whose rewards follow the flags alone (ManiSkill's sparse reward is success - fail) or are 0."""


def only_flags_problem(meta: RecordingMeta) -> str | None:
    """Why a replay of a recording with `meta` could verify nothing: it holds no env states, observations or contact
    forces, and no rewards but flag-driven ones (a ManiSkill RecordEpisode file made with record_env_state=False and
    obs_mode "none"), so only the flags would be compared, and those (all False, in most episodes) match whatever
    the trajectory did. None: the recording holds something that follows the trajectory."""
    if meta.state_layout or meta.obs_layout or meta.contact_channels:
        return None
    if "rewards" not in meta.unknown and meta.reward_mode not in _FLAG_REWARD_MODES:
        return None
    held = ("no env_states, observations or rewards" if "rewards" in meta.unknown else
            f"no env_states or observations, and its rewards are {meta.reward_mode}")
    flags = ", ".join(f for f in FLAG_FIELDS if f not in meta.unknown)
    return (f"holds {held} (recorded without them): a replay could compare only its flags ({flags}), which do not "
            f"tell whether the trajectory reproduced; {WITH_ENV_STATES}")


def recording_limits(unknown: list[str]) -> list[str]:
    """The limits of a replay of a recording that does not hold `unknown`, one line each."""
    return [_LIMITS[u] for u in unknown if u in _LIMITS]


def checked_groups(keys: list[str]) -> list[str]:
    """What a comparison's keys cover, in a fixed order: ``env_states``, ``obs``, ``contacts``, ``info``,
    ``rewards`` and each flag."""
    groups = {k.split("/", 1)[0].split("[", 1)[0] for k in keys}
    return [g for g in CHECK_ORDER if g in groups]


@dataclass(frozen=True)
class HistoryEntry:
    """What an actions replay ran before an episode to give its scene the history it had when recorded (PhysX's CPU
    results depend on it, `simreel.verdicts.scene_history`): `episodes` predecessors, `steps` steps of them (one:
    only the last step of the one right before it, from its recorded state), and `why`."""

    episodes: int
    steps: int
    why: str

    def describe(self) -> str:
        """The console's ``history:`` line."""
        return f"{self.episodes} predecessor episode(s), {self.steps} step(s) replayed: {self.why}"

    def to_json(self) -> dict[str, Any]:
        return {"episodes": self.episodes, "steps": self.steps, "why": self.why}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> HistoryEntry:
        return cls(int(d["episodes"]), int(d["steps"]), str(d["why"]))


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
    keys_compared: int = 0
    error: str | None = None
    """Why the episode could not be replayed (verdict ``error``)."""
    per_step: dict[str, list[float]] = field(default_factory=dict)
    """Key -> its error at every compared row, where a report carries them (a conversion's tracking errors)."""
    scene_differences: list[SceneDifference] | None = None
    """Where the replaying scene differs from the recorded fingerprint, found at the reset before any step (None: not
    compared, the recording has none)."""
    explanation: Explanation | None = None
    """Why it diverged (`simreel.replay.explain.explain`); None unless the verdict is ``diverged``."""
    history: HistoryEntry | None = None
    """What was replayed before it for its scene's history (None: not an actions replay of a file's episode)."""

    @classmethod
    def from_comparison(cls, recorded: Episode | EpisodeRows, cmp: EpisodeComparison, *, notes: list[str],
                        limits: list[str], seconds: float) -> EpisodeReport:
        """The report of `recorded`'s replay (the episode, or the rows it was read in), judged by `cmp`, with the
        replay's notes and limits."""
        return cls(
            index=recorded.meta.index,
            seed=recorded.meta.seed,
            length=recorded.length,
            verdict=cmp.verdict,
            first_divergence=cmp.first_divergence,
            max_abs_error=cmp.max_abs_error,
            tolerance=cmp.tolerance,
            diverged_keys=cmp.diverged_keys,
            notes=[*notes, *cmp.not_compared],
            limits=[*limits, *cmp.not_compared],
            seconds=seconds,
            checked=checked_groups(list(cmp.errors)),
            keys_compared=len(cmp.max_abs_error),
        )

    @classmethod
    def errored(cls, index: int, length: int, error: str) -> EpisodeReport:
        """The report of an episode that could not be replayed, and why."""
        return cls(index=index, seed=None, length=length, verdict="error", first_divergence=None, max_abs_error={},
                   error=error)

    @property
    def ok(self) -> bool:
        """It verified: exact or within tolerance."""
        return self.verdict in VERIFIED

    def worst(self, n: int = 3) -> list[tuple[str, float, float]]:
        """Up to n keys that left their tolerance (or came closest), largest error/tolerance first."""
        return worst_keys(self.max_abs_error, self.tolerance, n)

    def to_json(self) -> dict[str, Any]:
        """The episode's entry in a report file: the keys that were not reproduced exactly, with their largest error
        and tolerance (every other of the `keys_compared` keys was exact)."""
        off = {k: v for k, v in self.max_abs_error.items() if v != 0.0}
        out = {
            "index": self.index,
            "seed": self.seed,
            "length": self.length,
            "verdict": self.verdict,
            "first_divergence": None if self.first_divergence is None else self.first_divergence.to_json(),
            "max_abs_error": {k: json_number(v) for k, v in off.items()},
            "tolerance": {k: json_number(self.tolerance.get(k, 0.0)) for k in off},
            "keys_compared": self.keys_compared,
            "diverged_keys": dict(self.diverged_keys),
            "notes": list(self.notes),
            "limits": list(self.limits),
            "checked": list(self.checked),
            "seconds": round(self.seconds, 4),
            **({"per_step": {k: [json_number(x) for x in v] for k, v in self.per_step.items()}} if self.per_step else {}),
        }
        if self.error is not None:
            out["error"] = self.error
        if self.scene_differences is not None:
            out["scene_differences"] = [d.to_json() for d in self.scene_differences]
        if self.explanation is not None:
            out["explanation"] = self.explanation.to_json()
        if self.history is not None:
            out["history"] = self.history.to_json()
        return out

    def verification(self) -> EpisodeVerification:
        """What a replayed episode written by ``simreel replay -o`` keeps of its report (`EpisodeMeta.verification`):
        verdict, first divergence, scene differences and explanation, for viewers of that file."""
        full = self.to_json()
        return EpisodeVerification(full["verdict"], full.get("first_divergence"), full.get("scene_differences"),
                                   full.get("explanation"))

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> EpisodeReport:
        """The report `to_json` wrote (its zero errors left out)."""
        first = d.get("first_divergence")
        return cls(
            index=int(d["index"]), seed=d.get("seed"), length=int(d.get("length") or 0), verdict=str(d["verdict"]),
            first_divergence=None if first is None else Divergence.from_json(first),
            max_abs_error={k: float(v) for k, v in d.get("max_abs_error", {}).items()},
            tolerance={k: float(v) for k, v in d.get("tolerance", {}).items()},
            diverged_keys=dict(d.get("diverged_keys", {})), notes=list(d.get("notes", [])),
            seconds=float(d.get("seconds", 0.0)), limits=list(d.get("limits", [])), checked=list(d.get("checked", [])),
            keys_compared=int(d.get("keys_compared", 0)), error=d.get("error"),
            per_step={k: [float(x) for x in v] for k, v in d.get("per_step", {}).items()},
            scene_differences=_scene_differences(d.get("scene_differences")),
            explanation=None if d.get("explanation") is None else Explanation.from_json(d["explanation"]),
            history=None if d.get("history") is None else HistoryEntry.from_json(d["history"]),
        )


def _scene_differences(items: list[Mapping[str, Any]] | None) -> list[SceneDifference] | None:
    return None if items is None else [SceneDifference.from_json(item) for item in items]


def episode_lines(e: EpisodeReport) -> list[str]:
    """An episode's row of the summary table, and under it: the scene differences (unless the explanation lists
    them), its worst keys and the explanation when it diverged, and its notes."""
    pad = f"  {'':>7} {'':>6}  {'':<17}"
    first = e.first_divergence.describe() if e.first_divergence else (e.error or "")
    lines = [f"  {e.index:>7} {e.length:>6}  {e.verdict:<17} {first}".rstrip()]
    if e.scene_differences and not (e.explanation and e.explanation.cause and e.explanation.cause.kind == "scene_differs"):
        shown = [d.describe() for d in e.scene_differences[:4]]
        more = f" (+{len(e.scene_differences) - 4} more)" if len(e.scene_differences) > 4 else ""
        lines.append(f"{pad} scene differs from the recording (found at the reset): " + "; ".join(shown) + more)
    if e.verdict == "diverged":
        also = [f"{k} {format_number(v)} (tol {format_number(t)})" for k, v, t in e.worst(len(e.max_abs_error))
                if k in e.diverged_keys and (e.first_divergence is None or k != e.first_divergence.key)]
        if also:
            lines.append(f"{pad} {len(e.diverged_keys)} keys left their tolerance; worst: " + ", ".join(also[:3]))
    if e.explanation is not None:
        lines += [f"{pad} {line}" for line in e.explanation.lines()]
    if e.history is not None and e.history.episodes:
        lines.append(f"{pad} history: {e.history.describe()}")
    lines += [f"{pad} note: {note}" for note in (e.notes if e.verdict != "exact" else e.limits)]  # always: unchecked
    return lines
