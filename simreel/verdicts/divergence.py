"""Why a replay diverged: the data around a first divergence, and the explanation built from it. Pure numpy.

`compare` says *where* a replay left its tolerance; this module gathers what a reader needs to say *why*:

- `episode_events`: what happened in the recorded episode, step by step: contacts that began or ended (pair
  channels, with the force), grasp changes and success flips (`info`), jumps of controller targets, termination.
- `error_growth`: how a key's error behaved around its divergence ("grew 12× in 3 steps", "constant offset").
- `divergence_onset`: where the run of non-zero state error that leads into the divergence began, and how
  small it was there ("after reset: 1e-08, float noise").
- `Cause` and `Explanation`: the classified cause with the evidence behind it, and everything above, as
  plain lines (`Explanation.lines`) and JSON (`to_json` / `from_json`).

The replay room classifies (it needs the simulator: one-step errors, a second reset, the scene fingerprint);
the viewer shows the same events and growth from the two episodes alone (`describe_divergence`) and the
replay's cause where `simreel replay -o` stored it. Steps are counted as `simreel.verdicts.compare` counts them: step
k is the outcome of action k (state row k + 1); step -1 is the state right after the reset.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.model.components import format_number, json_number
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel
from simreel.verdicts.compare import Divergence, EpisodeComparison

__all__ = [
    "CAUSES",
    "CONTACT_THRESHOLD_N",
    "FLOAT_NOISE",
    "EVENTS_BEFORE",
    "EVENTS_AFTER",
    "EpisodeEvent",
    "episode_events",
    "ErrorGrowth",
    "error_growth",
    "DivergenceOnset",
    "divergence_onset",
    "Cause",
    "Explanation",
    "describe_divergence",
    "step_of_state_row",
    "compares_states",
]

CAUSES = (
    "scene_differs",
    "input_inconsistent",
    "reset_not_reproducible",
    "state_not_captured",
    "task_differs",
    "amplification",
    "restore_difference",
    "control_mode_differs",
    "undetermined",
)
"""Kinds of `Cause`, the order in which the replay room tries them."""
CONTACT_THRESHOLD_N = 1e-6
"""A contact channel whose force is at or below this magnitude (newtons) counts as no contact."""
FLOAT_NOISE = 1e-6
"""Differences at or below this (metres, radians, m/s) are float noise: a few float32 ulps of values near 1."""
EVENTS_BEFORE = 10
EVENTS_AFTER = 3
"""An explanation lists the events of the steps from EVENTS_BEFORE before the first divergence (or from its
onset, if earlier) to EVENTS_AFTER after it."""
GROWTH_STEPS = 3
"""Steps after a divergence over which `error_growth` judges the trend."""


def step_of_state_row(row: int) -> int:
    """The step whose outcome state row `row` is (row 0, after the reset: -1)."""
    return int(row) - 1


# ------------------------------------------------------------------------------------------------- events
@dataclass(frozen=True)
class EpisodeEvent:
    """Something that happened at one step of an episode.

    `kind`: ``contact_begins`` / ``contact_ends`` (`subject`: the pair ``a:b``, `value`: its force in newtons, after
    it began or before it ended), ``grasp_begins`` / ``grasp_ends`` (`subject`: the info key), ``success`` /
    ``success_lost``, ``fail``, ``controller_jump`` (`subject`: the controller key, `value`: the jump), ``terminated``,
    ``truncated``.
    """

    step: int
    kind: str
    subject: str = ""
    value: float | None = None

    def describe(self) -> str:
        v = "" if self.value is None else format_number(self.value)
        text = {
            "contact_begins": f"contact {self.subject} begins ({v} N)",
            "contact_ends": f"contact {self.subject} ends (was {v} N)",
            "grasp_begins": f"grasp begins ({self.subject})",
            "grasp_ends": f"grasp ends ({self.subject})",
            "success": "success",
            "success_lost": "success lost",
            "fail": "fail",
            "controller_jump": f"controller target {self.subject} jumps by {v}",
            "terminated": "terminated",
            "truncated": "truncated",
        }.get(self.kind, f"{self.kind} {self.subject}".strip())
        return f"step {self.step}: {text}"

    def to_json(self) -> dict[str, Any]:
        return {"step": self.step, "kind": self.kind, "subject": self.subject,
                "value": None if self.value is None else json_number(self.value), "text": self.describe()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> EpisodeEvent:
        value = d.get("value")
        return cls(int(d["step"]), str(d["kind"]), str(d.get("subject", "")),
                   None if value is None else float(value))


def _turns(flags: np.ndarray, *, starts_off: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Indices where a bool series turns on and where it turns off. `starts_off`: it was off before its first row
    (success); else its first row is how things were when the episode began (a resting contact), not a change."""
    f = np.asarray(flags, bool).astype(np.int8)
    if not len(f):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.diff(np.concatenate([[0 if starts_off else f[0]], f]))
    return np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]


def _contact_events(forces: np.ndarray | None, channels: Sequence[ContactChannel]) -> list[EpisodeEvent]:
    if forces is None or not len(forces):
        return []
    mags = np.linalg.norm(forces.astype(np.float64), axis=-1)
    events = []
    for c, ch in enumerate(channels):
        if ch.kind != "pair" or c >= mags.shape[1]:
            continue
        on, off = _turns(mags[:, c] > CONTACT_THRESHOLD_N, starts_off=False)
        events += [EpisodeEvent(int(t), "contact_begins", ch.name, float(mags[t, c])) for t in on]
        events += [EpisodeEvent(int(t), "contact_ends", ch.name, float(mags[t - 1, c])) for t in off]
    return events


def _flag_events(episode: Episode) -> list[EpisodeEvent]:
    events = []
    if episode.success is not None:  # None: the file holds no success (some of ManiSkill's own)
        on, off = _turns(episode.success)
        events += [EpisodeEvent(int(t), "success") for t in on]
        events += [EpisodeEvent(int(t), "success_lost") for t in off]
    if episode.fail is not None:
        events += [EpisodeEvent(int(t), "fail") for t in _turns(episode.fail)[0]]
    for key, values in episode.info.items():
        if "grasp" in key and values.ndim == 1 and values.dtype.kind in "biu":
            on, off = _turns(values != 0, starts_off=False)
            events += [EpisodeEvent(int(t), "grasp_begins", f"info/{key}") for t in on]
            events += [EpisodeEvent(int(t), "grasp_ends", f"info/{key}") for t in off]
    for flag in ("terminated", "truncated"):
        hits = np.nonzero(np.asarray(getattr(episode, flag), bool))[0]
        if len(hits):
            events.append(EpisodeEvent(int(hits[0]), flag))
    return events


def _controller_events(states: Mapping[str, np.ndarray]) -> list[EpisodeEvent]:
    """Steps where a controller target moved 10× more than its median move (and by more than 1e-3)."""
    events = []
    for key, rows in states.items():
        if not key.startswith("controller/") or len(rows) < 3:
            continue
        moves = np.abs(np.diff(rows.reshape(len(rows), -1).astype(np.float64), axis=0)).max(axis=1)
        moving = moves[moves > 0]
        if not moving.size:
            continue
        limit = max(10.0 * float(np.median(moving)), 1e-3)
        events += [EpisodeEvent(int(t), "controller_jump", key, float(moves[t])) for t in np.nonzero(moves > limit)[0]]
    return events


def episode_events(episode: Episode, channels: Sequence[ContactChannel] = (), *, first: int | None = None,
                   last: int | None = None) -> list[EpisodeEvent]:
    """Every event of `episode` (see `EpisodeEvent`) at steps `first`..`last` (inclusive; None: no bound), in step
    order. `channels` name the columns of `episode.contact_forces` (the recording's `contact_channels`)."""
    events = _contact_events(episode.contact_forces, channels) + _flag_events(episode)
    events += _controller_events(episode.env_states)
    lo = -math.inf if first is None else first
    hi = math.inf if last is None else last
    return sorted((e for e in events if lo <= e.step <= hi), key=lambda e: (e.step, e.kind, e.subject))


# ------------------------------------------------------------------------------------------------- errors
def _error_steps(comparison: EpisodeComparison, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, errors) of `key`: state and observation keys have a row per state (the first is step -1)."""
    err = comparison.errors[key]
    per_state = key.startswith(("env_states/", "obs/"))
    start = -1 if per_state else 0
    return np.arange(start, start + len(err)), err


@dataclass(frozen=True)
class ErrorGrowth:
    """How one key's error behaved around the step where it left its tolerance.

    `steps`/`errors`: its error curve over the explanation's window; `trend`: ``grew``, ``constant offset``,
    ``shrank``, ``fluctuates`` or ``no later steps``, judged from its error `span` steps after `step` (`factor`:
    that error over the error at `step`).
    """

    key: str
    tolerance: float
    step: int
    error: float
    trend: str
    factor: float | None
    span: int
    steps: list[int] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)

    def describe(self) -> str:
        where = "after reset" if self.step < 0 else f"at step {self.step}"
        head = f"{self.key}: {format_number(self.error)} {where} (tolerance {format_number(self.tolerance)})"
        if self.trend == "grew":
            return f"{head}, grew {format_number(self.factor or 0)}× in {self.span} steps"
        if self.trend == "no later steps":
            return f"{head}, the last step compared"
        if self.trend == _NOT_FINITE:
            return f"{head}, {_NOT_FINITE}"
        return f"{head}, {self.trend} (×{format_number(self.factor or 0)} after {self.span} steps)"

    def to_json(self) -> dict[str, Any]:
        return {"key": self.key, "tolerance": json_number(self.tolerance), "step": self.step,
                "error": json_number(self.error), "trend": self.trend,
                "factor": None if self.factor is None else json_number(self.factor), "span": self.span,
                "steps": list(self.steps), "errors": [json_number(e) for e in self.errors], "text": self.describe()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ErrorGrowth:
        factor = d.get("factor")
        return cls(str(d["key"]), float(d["tolerance"]), int(d["step"]), float(d["error"]), str(d["trend"]),
                   None if factor is None else float(factor), int(d.get("span", 0)),
                   [int(s) for s in d.get("steps", [])], [float(e) for e in d.get("errors", [])])


_NOT_FINITE = "no trend: NaN or infinity in the errors (the recording or the replay holds such values)"


def _trend(after: np.ndarray, at: float) -> tuple[str, float | None]:
    if not len(after):
        return "no later steps", None
    if not (math.isfinite(at) and np.isfinite(after).all()):
        return _NOT_FINITE, None
    factor = float(after[-1] / at) if at > 0 else math.inf
    ratios = after / at if at > 0 else np.full(len(after), math.inf)
    if factor >= 2.0:
        return "grew", factor
    if np.all((ratios >= 0.5) & (ratios <= 2.0)):
        return "constant offset", factor
    if factor < 0.5:
        return "shrank", factor
    return "fluctuates", factor


def error_growth(comparison: EpisodeComparison, key: str, step: int, window: tuple[int, int]) -> ErrorGrowth:
    """The growth of `key`'s error from `step` (where it left its tolerance) over `GROWTH_STEPS` steps, with its
    curve over the steps `window` (inclusive)."""
    steps, err = _error_steps(comparison, key)
    at = int(np.searchsorted(steps, step))
    after = err[at + 1 : at + 1 + GROWTH_STEPS]
    trend, factor = _trend(after, float(err[at]))
    shown = (steps >= window[0]) & (steps <= window[1])
    return ErrorGrowth(key, float(comparison.tolerance[key]), step, float(err[at]), trend, factor, len(after),
                       [int(s) for s in steps[shown]], [float(e) for e in err[shown]])


@dataclass(frozen=True)
class DivergenceOnset:
    """Where the unbroken run of non-zero state error that leads into a divergence began.

    `key`/`error`: the largest state difference at that step; `ratio`: the largest error/tolerance there;
    `growth`: the largest error/tolerance at the divergence over `ratio`.
    """

    step: int
    key: str
    error: float
    ratio: float
    growth: float

    @property
    def float_noise(self) -> bool:
        return self.error <= FLOAT_NOISE

    def describe(self) -> str:
        where = "after reset" if self.step < 0 else f"at step {self.step}"
        noise = " (float noise)" if self.float_noise else ""
        head = f"the first state difference: {where}, {self.key} off by {format_number(self.error)}{noise}"
        if not math.isfinite(self.growth):
            return f"{head}; no ratio to the divergence: NaN or infinity in the errors there"
        if self.growth <= 1.0:
            return f"{head}; the state matched the recording before it"
        return f"{head}; {format_number(self.growth)}× that (relative to tolerance) at the divergence"

    def to_json(self) -> dict[str, Any]:
        return {"step": self.step, "key": self.key, "error": json_number(self.error),
                "ratio": json_number(self.ratio), "growth": json_number(self.growth),
                "float_noise": self.float_noise, "text": self.describe()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> DivergenceOnset:
        return cls(int(d["step"]), str(d["key"]), float(d["error"]), float(d["ratio"]), float(d["growth"]))


def compares_states(comparison: EpisodeComparison) -> bool:
    """Whether `comparison` holds state keys: a file recorded without env states has none, so nothing can say where a
    state difference began, nor that the state matched."""
    return any(k.startswith("env_states/") for k in comparison.errors)


def _state_ratios(comparison: EpisodeComparison) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(largest error/tolerance per state row, largest error per state row, the key of each) over state keys."""
    keys = [k for k in comparison.errors if k.startswith("env_states/")]
    if not keys:
        return np.zeros(0), np.zeros(0), []
    err = np.stack([comparison.errors[k] for k in keys])
    tol = np.array([comparison.tolerance[k] for k in keys])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(err > 0, err / np.where(tol > 0, tol, np.nan), 0.0)
    ratio = np.where(np.isnan(ratio), np.inf, ratio)
    worst = err.argmax(axis=0)
    return ratio.max(axis=0), err.max(axis=0), [keys[i] for i in worst]


def divergence_onset(comparison: EpisodeComparison, step: int) -> DivergenceOnset | None:
    """The onset of the state error leading into the divergence at `step` (None: the state matched up to it, or no
    state was compared: `compares_states`)."""
    ratio, err, worst = _state_ratios(comparison)
    row = min(step + 1, len(err) - 1)
    if row < 0 or not len(err) or err[row] == 0 and (row == 0 or err[row - 1] == 0):
        return None
    if err[row] == 0:
        row -= 1  # a per-step value diverged while the state difference ran up to the step before
    start = row
    while start > 0 and err[start - 1] > 0:
        start -= 1
    at_divergence = float(ratio[min(step + 1, len(ratio) - 1)])
    finite = math.isfinite(at_divergence) and math.isfinite(ratio[start]) and ratio[start] > 0
    growth = at_divergence / float(ratio[start]) if finite else math.nan  # NaN: no ratio (`describe`)
    return DivergenceOnset(step_of_state_row(start), worst[start], float(err[start]), float(ratio[start]), growth)


# ------------------------------------------------------------------------------------------------- explanation
@dataclass
class Cause:
    """The likely cause of a divergence, in one plain sentence, with the data lines that back it."""

    kind: str
    """One of `CAUSES`."""
    summary: str
    step: int | None = None
    key: str | None = None
    evidence: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "summary": self.summary, "step": self.step, "key": self.key,
                "evidence": list(self.evidence)}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Cause:
        step = d.get("step")
        return cls(str(d["kind"]), str(d["summary"]), None if step is None else int(step), d.get("key"),
                   [str(e) for e in d.get("evidence", [])])


@dataclass
class Explanation:
    """Why an episode's replay diverged: the classified `cause` (None: not classified, data only), the `events`
    around the first divergence, the error `growth` of the keys that left their tolerance, the `onset` of the
    state difference, and what was `checked` to get there."""

    divergence: Divergence
    cause: Cause | None = None
    events: list[EpisodeEvent] = field(default_factory=list)
    growth: list[ErrorGrowth] = field(default_factory=list)
    onset: DivergenceOnset | None = None
    checked: list[str] = field(default_factory=list)

    def lines(self, *, max_events: int = 6) -> list[str]:
        """The explanation in plain words, one fact per line (the terminal summary and the viewer's log)."""
        out = []
        if self.cause is not None:
            out.append(f"why: {self.cause.summary}")
            out += [f"  {line}" for line in self.cause.evidence]
        out += [f"error: {g.describe()}" for g in self.growth]
        if self.onset is not None:
            out.append(f"onset: {self.onset.describe()}")
        near = sorted(self.events, key=lambda e: (abs(e.step - self.divergence.step), e.step))[:max_events]
        if near:
            out.append("events: " + "; ".join(e.describe() for e in sorted(near, key=lambda e: e.step)))
        else:
            out.append("events: none in the recording around the divergence (no contact, grasp or success change)")
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "divergence": self.divergence.to_json(),
            "cause": None if self.cause is None else self.cause.to_json(),
            "events": [e.to_json() for e in self.events],
            "growth": [g.to_json() for g in self.growth],
            "onset": None if self.onset is None else self.onset.to_json(),
            "checked": list(self.checked),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Explanation:
        div = d["divergence"]
        divergence = Divergence(int(div["step"]), str(div["key"]), float(div["error"]), float(div["tolerance"]),
                                str(div.get("at", "step")))
        cause = d.get("cause")
        onset = d.get("onset")
        return cls(
            divergence=divergence,
            cause=None if cause is None else Cause.from_json(cause),
            events=[EpisodeEvent.from_json(e) for e in d.get("events", [])],
            growth=[ErrorGrowth.from_json(g) for g in d.get("growth", [])],
            onset=None if onset is None else DivergenceOnset.from_json(onset),
            checked=[str(c) for c in d.get("checked", [])],
        )


def _growth_keys(comparison: EpisodeComparison, first: str, n: int) -> list[str]:
    """The first divergent key, then up to n - 1 other keys that left their tolerance, earliest first."""
    others = sorted((k for k in comparison.diverged_keys if k != first), key=lambda k: (comparison.diverged_keys[k], k))
    return [first, *others[: n - 1]]


def describe_divergence(recorded: Episode, comparison: EpisodeComparison, channels: Iterable[ContactChannel] = (),
                        *, growth_keys: int = 3, steps_on: bool = True) -> Explanation | None:
    """The data part of an explanation (events, error growth, onset; no cause) of `comparison`'s first divergence,
    from the recorded episode and the comparison alone; None when nothing diverged. `steps_on`: whether the replay
    stepped on from its own states (``actions`` mode); where every step started from a restored recorded state
    (``step``, ``states``), no difference carries from one step to the next, and no onset is given."""
    d = comparison.first_divergence
    if d is None:
        return None
    step = -1 if d.at == "reset" else d.step
    onset = divergence_onset(comparison, step) if steps_on else None
    start = step - EVENTS_BEFORE if onset is None else min(step - EVENTS_BEFORE, onset.step)
    window = (max(start, -1), step + EVENTS_AFTER)
    events = episode_events(recorded, list(channels), first=window[0], last=window[1])
    growth = [error_growth(comparison, key, step if key == d.key else comparison.diverged_keys[key], window)
              for key in _growth_keys(comparison, d.key, growth_keys)]
    return Explanation(divergence=d, events=events, growth=growth, onset=onset)
