"""Explain a diverged replay: gather the evidence with the simulator and classify the likely cause.

`explain_divergence` starts from the data of the two episodes (`simreel.verdicts.divergence.describe_divergence`: events
around the first divergence, error growth, onset) and adds what only the simulator can tell, trying the causes
in this order and keeping the first the data supports:

1. ``scene_differs``: the replaying scene's fingerprint (masses, shapes, materials, joints, controllers) differs
   from the recording's; found at the reset, before any step. (Another build, i.e. versions, sim backend or sim
   config, is named the same way, but only when none of the step-level causes below holds.) Then a recorded
   quaternion that is no rotation (its norm off 1: zeroed, scaled): ``input_inconsistent``, the file's data is
   what no simulator writes.
2. For a divergence right after the reset: two more resets with the recorded seed and options. They agree with
   each other but not with the recording: ``input_inconsistent`` (the seed or options do not produce the recorded
   initial state); they disagree: ``reset_not_reproducible``.
3. The one-step errors of ``--mode step`` (restore the recorded state t, step action t, compare with recorded
   t + 1) at the divergent step k and the `NEIGHBOURS` steps on each side, and the same from a second instance,
   reset to another episode first. In ``--mode step`` the replay's own comparison is the one-step errors (a second
   run would start from another PhysX history and could contradict the report). A step is off when it leaves step
   mode's tolerances, or when what the task computes there (reward, info, a flag) is off by at least half the
   replay's own divergence while the state after the step is reproduced within the replay's tolerances (the same
   state gave another value). Then, in this order:

   - the two instances disagree at k: step k depends on what the env held before the restore:
     ``state_not_captured``;
   - only step k is off: ``input_inconsistent`` (the recorded action k does not give the recorded step k, or the
     recorded reward / info / flag at k is not what the task computes there);
   - only k and k + 1 are off, the state after k among what is off: the recorded state after step k (row k + 1) is
     not what action k gives, and does not lead to row k + 2: ``input_inconsistent`` naming that state row;
   - every step checked is off in what the task computes only, the states reproduced, and the second instance
     agrees: the task computes something else from the same state than was recorded (its code or build changed, or
     the recorded values were altered): ``task_differs``. Without a second instance (ManiSkill's files: their
     scenes cannot be rebuilt for certain) the evidence cannot tell that from state the dict lacks: undetermined,
     naming both.

   Nothing is decided at k while step k reproduces; then the same is tried at the onset of the state difference
   when it lies before the steps checked (an action altered long before the error left its tolerance). Without a
   second instance the causes above say that its check could not run. A file without env states gets none of the
   checks that need them (the one-step errors, the reset's state, the other control modes), and says so.
4. Each step alone reproduces the recording, but the state began to differ by float noise and grew:
   ``amplification`` (through the contact events on the way, when there are some). Only where the replay steps
   on from its own states (``actions``, ``--resync``): in ``--mode step`` and ``states`` every step starts from a
   restored recorded state, so nothing can grow across steps.
5. The difference appeared in the first step after the replay restored a recorded state (``--resync``, an
   unseeded episode's start) and is no larger than one step from a restored state is: ``restore_difference``.
6. No step around k gives its recorded state from the restored one, but each does in another of the robot's
   control modes whose actions have the recorded size: ``control_mode_differs`` (the file names the wrong mode).
7. Otherwise ``undetermined``, with what was checked.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.model.components import Tolerances, component_error, components_of, format_number, not_rotations
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel
from simreel.replay.run.engine import EpisodeReplayer, ReplayedEpisode
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.rebuild import another_episode
from simreel.sim.state import state_row
from simreel.verdicts.compare import EpisodeComparison, compare_episode
from simreel.verdicts.divergence import Cause, Explanation, compares_states, describe_divergence

__all__ = ["ExplainContext", "explain_divergence", "NEIGHBOURS"]

NEIGHBOURS = 2
"""Steps on each side of the divergent step whose one-step errors are checked."""
_SCENE_LINES = 8
SHARE_OF_DIVERGENCE = 0.5
"""A value the task computes that one step from a restored state puts off by at least this share of the replay's own
divergence on the same key, the state after the step reproduced within the replay's tolerances, is off whatever step
mode's (looser) tolerance says: a one-step error as large as the divergence itself is not a reproduction."""
_NO_STATES = ("the file holds no states: the one-step errors, the second instance, the reset's state and the other "
              "control modes need them and were not checked, and where a state difference began cannot be told")


@dataclass(frozen=True)
class ExplainContext:
    """What an explanation needs besides the two episodes: how the replay ran and what differed before it ran."""

    mode: str
    resync: int | None
    channels: list[ContactChannel]
    env_id: str
    build_differences: list[str] = field(default_factory=list)
    """Version, sim backend and sim config differences (`simreel.replay.run.fingerprint.fingerprint_differences`)."""


@dataclass(frozen=True)
class _Worst:
    """The key furthest out of (or closest to) its tolerance at one step of a comparison, or between two states
    (step -1: the reset)."""

    step: int
    key: str
    error: float
    tolerance: float
    judged_by: str = "step tolerance"
    """What `tolerance` is: step mode's tolerance, or a share of the replay's divergence (`SHARE_OF_DIVERGENCE`)."""

    @property
    def ratio(self) -> float:
        """The error in units of its tolerance: above 1 is out of tolerance; any error beyond a zero tolerance is."""
        if self.error == 0:
            return 0.0
        return math.inf if self.tolerance == 0 else self.error / self.tolerance

    def describe(self) -> str:
        """One step's worst key, with the step tolerance it is judged by."""
        return f"{self.key} off by {format_number(self.error)} ({self.judged_by} {format_number(self.tolerance)})"

    def describe_states(self) -> str:
        """Two states' largest difference, or that they are identical."""
        if self.error == 0:
            return "identical"
        return f"{self.key} off by {format_number(self.error)}"


_COMPUTED = ("info/", "rewards", "obs/", "terminated", "truncated", "success", "fail")
"""Keys of what a task computes from its state (not the physics: state leaves and contact forces)."""


def _worst_at(cmp: EpisodeComparison, step: int, *, only: str | tuple[str, ...] = "") -> _Worst:
    """The key of `cmp` furthest out of its tolerance at `step`, among the keys starting with `only` (all: "").

    Observations are left out where the state is compared: they are computed from it, and one step after a restore
    their velocity entries carry the same cache noise as the state's velocities, which step mode's observation
    tolerance is not made for."""
    best = _Worst(step, "", 0.0, 1.0)
    has_states = compares_states(cmp)
    for key, err in cmp.errors.items():
        per_state = key.startswith(("env_states/", "obs/"))
        if not key.startswith(only) or (has_states and key.startswith("obs/")):
            continue
        row = step + 1 if per_state else step
        if not 0 <= row < len(err):
            continue
        cand = _Worst(step, key, float(err[row]), float(cmp.tolerance[key]))
        if cand.ratio > best.ratio:
            best = cand
    return best


def _inconsistent_step(k: int, physics: _Worst, worst: _Worst, length: int) -> str:
    """Why step k of a recording is inconsistent (the steps around it reproduce): its recorded action does not give its
    recorded state, or (the state reproduced) what the task computes from it is not what was recorded."""
    if physics.ratio > 1:
        return (f"the recorded action {k} does not produce the recorded step {k} even from the exactly restored state, "
                "while the steps around it do")
    said = (f"the recorded {worst.key} at step {k} is not what the task computes there from the exactly restored state "
            f"and action (the state after the step is reproduced), while the steps around it are")
    if worst.key == "truncated" and k == length - 1:
        said += "; at the last step, a time limit other than the replaying env's would do that"
    return said


@dataclass(frozen=True)
class _Unexplained:
    """What the one-step check found without deciding a cause: a phrase for the summary and its evidence lines."""

    found: str
    evidence: list[str]


class _Explainer:
    """One diverged episode's explanation: the data part first, then the causes tried in the module's order."""

    def __init__(self, replayer: EpisodeReplayer, recorded: Episode, replayed: ReplayedEpisode,
                 cmp: EpisodeComparison, ctx: ExplainContext) -> None:
        self.replayer = replayer
        self.recorded = recorded
        self.replayed = replayed
        self.cmp = cmp
        self.ctx = ctx
        self.explanation = describe_divergence(recorded, cmp, ctx.channels, steps_on=self.steps_on)
        d = cmp.first_divergence
        self.step = -1 if d.at == "reset" else d.step
        self.one_step: EpisodeComparison | None = None
        self.between: EpisodeComparison | None = None
        self.other_seed: int | None = None
        self.no_second: str | None = None
        """Why there is no second instance (None: there is one, or the one-step errors were not measured)."""
        self.unexplained: _Unexplained | None = None

    @property
    def checked(self) -> list[str]:
        return self.explanation.checked

    @property
    def has_states(self) -> bool:
        """Whether the recording holds env states (a ManiSkill file recorded with record_env_state=False holds none)."""
        return bool(self.recorded.env_states)

    @property
    def steps_on(self) -> bool:
        """Whether the replay stepped on from its own states, so a difference could grow across steps (``actions``,
        with or without ``--resync``); in ``step`` and ``states`` mode every step starts from a restored state."""
        return self.ctx.mode == "actions"

    def run(self) -> Explanation:
        scene = self._scene() or self._no_rotation()
        if self.step < 0:
            cause = scene or self._reset()
        else:
            cause = (scene or self._one_step_cause() or self._amplification() or self._restore_difference()
                     or self._other_control_mode())
        self.explanation.cause = cause or self._build() or self._undetermined()
        return self.explanation

    # -- 1. the scene
    def _scene(self) -> Cause | None:
        diffs: list[SceneDifference] | None = self.replayed.scene_differences
        if diffs is None:
            self.checked.append("scene fingerprint: not compared (the recording has none)")
            diffs = []
        else:
            self.checked.append(f"scene fingerprint compared at the reset: {len(diffs)} difference(s)")
        return self._differs("scene", [d.describe() for d in diffs] + list(self.ctx.build_differences) if diffs else [])

    def _build(self) -> Cause | None:
        """Other versions, sim backend or sim config: named when no step-level cause was found (a Python patch
        release beside an altered action is not the reason)."""
        return self._differs("build (versions, sim backend or sim config)", list(self.ctx.build_differences))

    def _differs(self, what: str, lines: list[str]) -> Cause | None:
        if not lines:
            return None
        more = [f"... {len(lines) - _SCENE_LINES} more"] if len(lines) > _SCENE_LINES else []
        return Cause("scene_differs", f"the replaying {what} differs from the recorded one ({lines[0]}), found at the "
                     "reset before any step was compared; a replay of another scene is expected to diverge",
                     step=None, key=None, evidence=lines[:_SCENE_LINES] + more)

    def _no_rotation(self) -> Cause | None:
        """The first recorded quaternion that is no rotation (its norm off 1: zeroed, scaled; `not_rotations`): data
        no simulator wrote, so the file is what is off, whatever else differs."""
        for path, rows in self.recorded.env_states.items():
            for comp in components_of(path, rows.shape[1:]):
                if not comp.quat:
                    continue
                bad = np.flatnonzero(not_rotations(np.asarray(rows[:, comp.start:comp.stop], np.float64)))
                if bad.size:
                    row, q = int(bad[0]), rows[int(bad[0]), comp.start:comp.stop]
                    norm = format_number(float(np.linalg.norm(np.asarray(q, np.float64))))
                    return Cause("input_inconsistent", f"input inconsistent: the recording's {comp.key} at state row "
                                 f"{row} is [{', '.join(format_number(float(x)) for x in q)}], no rotation (norm {norm}); no "
                                 "simulator writes that: the file was damaged or altered", step=self.step, key=comp.key,
                                 evidence=[f"{bad.size} state row(s) of {comp.key} hold no rotation, the first row {row}"])
        return None

    # -- 2. the reset
    def _reset(self) -> Cause | None:
        ep = self.recorded.meta
        first = self.replayer.initial_state(ep)
        second = self.replayer.initial_state(ep)
        tol = Tolerances.for_mode("states")
        again = _state_difference(first, second, tol)
        self.checked.append(f"reset twice with seed {ep.seed} and the recorded options")
        how = f"seed {ep.seed}" + (f" and options {ep.reset_options}" if ep.reset_options else "")
        if again.ratio > 1:
            return Cause("reset_not_reproducible", f"the task's reset is not reproducible: two resets with {how} give "
                         f"different states ({again.describe_states()}), so it draws from something the seed does not "
                         "set (torch or numpy's global RNG, say)", step=-1, key=again.key,
                         evidence=[f"reset 1 vs reset 2: {again.describe_states()}"] + self._reset_vs_recorded(first))
        if not self.has_states:
            self.checked.append(_NO_STATES)
            return None
        recorded = _state_difference(state_row(self.recorded.env_states, 0), first, tol)
        if recorded.ratio > 1:
            return Cause("input_inconsistent", f"input inconsistent with the recording at the reset: {how} gives the same "
                         f"initial state twice, but not the recorded one ({recorded.describe_states()})", step=-1,
                         key=recorded.key, evidence=[f"reset 1 vs reset 2: {again.describe_states()}",
                                                     f"reset vs the recording: {recorded.describe_states()}"])
        return None

    def _reset_vs_recorded(self, reset: dict[str, Any]) -> list[str]:
        if not self.has_states:
            return ["reset 1 vs the recording: not compared (the file holds no states)"]
        recorded = _state_difference(state_row(self.recorded.env_states, 0), reset, Tolerances.for_mode("states"))
        return [f"reset 1 vs the recording: {recorded.describe_states()}"]

    # -- 3. one step from the restored state
    def _stepped(self, episode: Episode) -> Episode | None:
        """`episode` replayed in step mode (None, with a note, where that fails)."""
        try:
            return self.replayer.replay(episode, mode="step", obs=False).episode
        except Exception as exc:  # noqa: BLE001 - a failed check is reported, the replay's verdict stands
            self.checked.append(f"one-step errors: not measured ({type(exc).__name__}: {exc})")
            return None

    def _one_step_errors(self) -> None:
        """A: one step from each restored state, the env reset to the episode (``--mode step``; in that mode the
        replay's own comparison); B: the same with the env reset to another episode of the same scene first. A vs the
        recording says whether a transition is reproduced; A vs B whether it depends on what the env held before the
        restore (state the dict lacks)."""
        tol = Tolerances.for_mode("step")
        own = self.ctx.mode == "step"
        a = self.replayed.episode if own and self.replayed.episode is not None else self._stepped(self.recorded)
        if a is None:
            return
        self.one_step = self.cmp if own else compare_episode(self.recorded, a, tol, channels=self.ctx.channels)
        other = _other_episode(self.recorded)
        if other is None:
            self.no_second = ("no second instance: the episode's scene cannot be rebuilt for certain (built by an "
                              "unseeded reset, or the file does not say whether its reset rebuilt it)")
            self.checked.append(self.no_second)
            return
        b = self._stepped(other)
        if b is not None:
            self.between = compare_episode(a, b, tol, channels=self.ctx.channels)
            self.other_seed = other.meta.seed

    def _one_step_cause(self) -> Cause | None:
        """The cause the one-step errors show at the divergent step, else at the onset of the state difference when
        that lies before the steps checked around it."""
        if not self.has_states:
            self.checked.append(_NO_STATES)
            return None
        self._one_step_errors()
        if self.one_step is None:
            return None
        cause = self._cause_at(self.step, self.cmp.first_divergence.key)
        onset = self.explanation.onset
        if cause is None and onset is not None and 0 <= onset.step < self._window()[0]:
            cause = self._cause_at(onset.step, onset.key)
            if cause is not None:
                cause.evidence.append(f"the state began to differ there ({onset.describe()}), before step {self.step} "
                                      "where the replay left its tolerance")
        return cause

    def _cause_at(self, k: int, key: str) -> Cause | None:
        """The cause the one-step errors around step k support (see the module's item 3), or None."""
        steps = self._window(k)
        worst = {t: self._worst(self.one_step, t) for t in steps}
        how = "the replay's own (--mode step)" if self.ctx.mode == "step" else \
            "restore state t, step action t; step tolerances"
        self.checked.append(f"one-step errors ({how}) at steps {_listed(steps)}")
        apart = None
        if self.between is not None:
            self.checked.append(f"the same after resetting to another episode (seed {self.other_seed}) first, step {k}")
            apart = self._worst(self.between, k)
        off = [t for t in steps if worst[t].ratio > 1]
        if apart is not None and apart.ratio > 1:
            return self._state_not_captured(k, key, worst, apart)
        if k not in off:
            return None
        physics = _worst_at(self.one_step, k, only="env_states/")
        if off == [k]:
            return self._inconsistent(k, key, _inconsistent_step(k, physics, worst[k], self.recorded.length), worst,
                                      apart)
        if off == [k, k + 1] and physics.ratio > 1:
            return self._inconsistent_state_row(k, key, worst, apart)
        if off == steps and all(_worst_at(self.one_step, t, only="env_states/").ratio <= 1 for t in steps):
            return self._task_differs(k, key, worst, apart)
        self.unexplained = _Unexplained(
            f"steps {_listed(off)} are not reproduced from their restored states",
            [f"steps {_listed(off)} are not reproduced from their restored states"
             + (", whatever the env held before the restore" if apart is not None else "")
             + f" ({worst[k].describe()} at step {k})"
             + (f"; steps {_listed([t for t in steps if t not in off])} are" if len(off) < len(steps) else ""),
             "not decided what differs there: the recorded actions or states, the physics, or a tolerance tighter "
             "than one step from a restored state holds could each do that", *self._second_instance(k, apart)])
        return None

    def _worst(self, cmp: EpisodeComparison, step: int) -> _Worst:
        """`_worst_at`, with the divergent key also judged against the divergence itself (`SHARE_OF_DIVERGENCE`)."""
        worst, share = _worst_at(cmp, step), self._divergence_share(cmp, step)
        return share if share is not None and share.ratio > worst.ratio else worst

    def _divergence_share(self, cmp: EpisodeComparison, step: int) -> _Worst | None:
        """The divergent key at `step` of `cmp` judged by `SHARE_OF_DIVERGENCE` of the divergence's error, where it is a
        value the task computes and the state after the step is reproduced within the replay's own tolerances (else
        None: a state off by more than those explains a computed value off too)."""
        d = self.cmp.first_divergence
        if not d.key.startswith(_COMPUTED) or d.key.startswith("obs/") or d.key not in cmp.errors or not d.error > 0:
            return None
        err = cmp.errors[d.key]
        if not 0 <= step < len(err) or not self._state_within_verdict(cmp, step):
            return None
        return _Worst(step, d.key, float(err[step]), SHARE_OF_DIVERGENCE * d.error,
                      judged_by=f"{format_number(SHARE_OF_DIVERGENCE)} × the replay's divergence,")

    def _state_within_verdict(self, cmp: EpisodeComparison, step: int) -> bool:
        """Whether every state key of `cmp` after `step` is within the tolerance the replay's verdict used."""
        keys = [key for key in cmp.errors if key.startswith("env_states/") and key in self.cmp.tolerance]
        return bool(keys) and all(float(cmp.errors[key][step + 1]) <= float(self.cmp.tolerance[key]) for key in keys)

    def _second_instance(self, k: int, apart: _Worst | None) -> list[str]:
        """The line on the second instance at step k: what it gave, or why it could not run."""
        if apart is not None:
            return [f"an instance reset to another episode (seed {self.other_seed}) before the restore gives the same "
                    "step " + (f"(largest difference: {apart.describe()})" if apart.error else "exactly")]
        if self.no_second is not None:
            return [f"whether step {k} depends on what the env held before the restore was not checked: "
                    f"{self.no_second}"]
        return []

    def _at(self, k: int, worst: dict[int, _Worst]) -> str:
        return f"step {k} from the exactly restored state {k}: " + (worst[k].describe() if worst[k].error else "exact")

    def _reproduced(self, worst: dict[int, _Worst], off: list[int]) -> str:
        """The line on the steps of the window that reproduce the recording."""
        fine = [w for t, w in worst.items() if t not in off]
        largest = max(fine, key=lambda w: w.ratio, default=None)
        tail = f" (largest: {largest.describe()})" if largest is not None and largest.error > 0 else " (exactly)"
        return f"steps {_listed([w.step for w in fine]) or 'none'} reproduce the recording from their restored " \
               f"states{tail}"

    def _inconsistent(self, k: int, key: str, why: str, worst: dict[int, _Worst], apart: _Worst | None) -> Cause:
        """Only step k is off: the recording's step k is not what its action gives (`why`: which part, and how)."""
        evidence = [self._at(k, worst), self._reproduced(worst, [k]), *self._second_instance(k, apart)]
        return Cause("input_inconsistent", f"input inconsistent with the recording at step {k}: " + why, step=k,
                     key=key, evidence=evidence)

    def _inconsistent_state_row(self, k: int, key: str, worst: dict[int, _Worst], apart: _Worst | None) -> Cause:
        """Steps k and k + 1 off, the rest reproduced: the recorded state after step k (row k + 1) is what is off: step
        k does not give it, and the step from it does not give the next recorded state."""
        evidence = [self._at(k, worst), f"step {k + 1} from the recorded state {k + 1}: {worst[k + 1].describe()}",
                    self._reproduced(worst, [k, k + 1])]
        later = _worst_at(self.cmp, k + 1, only="env_states/")
        confirmed = self.steps_on and k + 1 not in self.replayed.restored_at and later.ratio <= 1
        if confirmed:
            evidence.append(f"the replay, which stepped on from its own state {k + 1} rather than the recorded one, "
                            f"gives the recorded state {k + 2} (" + ("exactly" if later.error == 0 else
                                                                     f"largest: {later.describe_states()}") + ")")
        evidence += self._second_instance(k, apart)
        alternative = "" if confirmed else f" (or actions {k} and {k + 1} both are)"
        return Cause("input_inconsistent", f"input inconsistent with the recording at step {k}: the recorded state after "
                     f"step {k} (state row {k + 1}) is not what action {k} gives from the exactly restored state {k}, "
                     f"and the step from it does not give the recorded state {k + 2}, while the steps around them "
                     f"reproduce the recording: that state row is off{alternative}", step=k, key=key, evidence=evidence)

    def _task_differs(self, k: int, key: str, worst: dict[int, _Worst], apart: _Worst | None) -> Cause | None:
        """Every step checked reproduces the state but not what the task computes from it: with a second instance that
        agrees, the task computes something else from the same state than was recorded (``task_differs``); without
        one, that cannot be told from state the dict lacks (left undetermined, naming both)."""
        steps = list(worst)
        computed = _worst_at(self.one_step, k, only=_COMPUTED)
        evidence = [self._at(k, worst), f"at every step checked ({_listed(steps)}) the state after the step is "
                    f"reproduced, but not what the task computes from it ({computed.describe()} at step {k})"]
        if apart is None:
            self.unexplained = _Unexplained(
                f"what the task computes is off at every step checked ({_listed(steps)}) while the state is reproduced: "
                "its code or build (a reward, evaluate(), the reward mode) differs from the recording's, or it depends "
                "on state its dict lacks; no second instance could tell which", [*evidence, *self._second_instance(k, None)])
            return None
        evidence += self._second_instance(k, apart) + list(self.ctx.build_differences)
        return Cause("task_differs", "task differs: from the same state the task computes something else than was "
                     f"recorded ({computed.key}), at every step checked and alike in an instance that held another "
                     "episode, so no missing state explains it: the task's code or build (its reward, evaluate(), the "
                     "reward mode) differs from the recording's, or the recorded values were altered", step=k, key=key,
                     evidence=evidence)

    def _state_not_captured(self, k: int, key: str, worst: dict[int, _Worst], apart: _Worst) -> Cause:
        """The step from a restored state depends on what the env held before the restore: two instances restored to
        the same state and given the same action disagree."""
        evidence = [self._at(k, worst)]
        physics = _worst_at(self.one_step, k, only="env_states/")
        computed = _worst_at(self.one_step, k, only=_COMPUTED)
        if physics.ratio <= 1 and computed.ratio > 1:
            evidence.append(f"the state after step {k} is reproduced ("
                            + (f"largest: {physics.describe()}" if physics.error > 0 else "exactly")
                            + f"), but not what the task computes from it: {computed.describe()}")
        evidence.append(f"restored into an instance reset to another episode (seed {self.other_seed}) first, step {k} "
                        f"differs: {apart.describe()} between the two")
        evidence += [f"step {t}: {w.describe()}" for t, w in worst.items() if t != k and w.ratio > 1]
        evidence.append(f"find the state the task keeps outside its state dict with `simreel audit {self.ctx.env_id}` "
                        "(--trajectory to audit along this recording)")
        return Cause("state_not_captured", f"state not captured: restoring the recorded state does not reproduce step {k}, "
                     "which depends on state the task's state dict does not hold", step=k, key=key, evidence=evidence)

    # -- 4. and 5. small differences that grew, or came from a restore
    def _one_step_fine(self) -> str:
        """The one-step check at the divergent step, with how large its error on the divergent key is beside the
        replay's own divergence: within step mode's tolerances but as large as the divergence is no reproduction."""
        if self.one_step is None:
            return "one-step errors not measured"
        w = _worst_at(self.one_step, self.step)
        share = self._share_of_divergence()
        found = w.describe() if w.error > 0 else "exactly"
        if share is not None and share >= SHARE_OF_DIVERGENCE:
            return f"step {self.step} alone is within step mode's tolerances ({found}), but {self._divergence_part()}"
        said = f"step {self.step} alone reproduces the recording ({found})"
        return said + (f"; {self._divergence_part()}" if share is not None else "")

    def _share_of_divergence(self) -> float | None:
        """The one-step error at the divergent step on the divergent key over the divergence's own error (None: not
        measured, or no error to compare with)."""
        d = self.cmp.first_divergence
        row = self.step + 1 if d.key.startswith(("env_states/", "obs/")) else self.step
        if self.one_step is None or d.key not in self.one_step.errors or not d.error > 0:
            return None
        err = self.one_step.errors[d.key]
        return float(err[row]) / d.error if 0 <= row < len(err) else None

    def _divergence_part(self) -> str:
        d, share = self.cmp.first_divergence, self._share_of_divergence()
        one = share * d.error
        return (f"one step alone puts {d.key} off by {format_number(one)}, {format_number(100 * share)}% of the replay's "
                f"own divergence there ({format_number(d.error)})")

    def _amplification(self) -> Cause | None:
        onset = self.explanation.onset
        # no onset where every step started from a restored state (`steps_on`): nothing grows across steps there
        if onset is None or not onset.float_noise or not onset.growth >= 10 or onset.step >= self.step:  # NaN: no ratio
            return None
        contacts = [e for e in self.explanation.events
                    if onset.step <= e.step <= self.step and e.kind in ("contact_begins", "contact_ends", "grasp_begins",
                                                                         "grasp_ends")]
        where = "after reset" if onset.step < 0 else f"at step {onset.step}"
        via = "through " + ", ".join(e.describe() for e in contacts[:3]) if contacts else \
            "with no contact beginning or ending on the way"
        restored = self._restore_before(onset.step)
        evidence = [onset.describe(), self._one_step_fine()]
        if restored is not None:
            evidence.append(f"the replay restored the recorded state before step {restored} ({self._restore_reason()})")
        return Cause("amplification", f"amplification of a tiny difference: the state first differed {where} by "
                     f"{format_number(onset.error)} (float noise) and grew {format_number(onset.growth)}× {via}, until "
                     f"{self.cmp.first_divergence.key} left its tolerance at step {self.step}", step=self.step,
                     key=self.cmp.first_divergence.key, evidence=evidence)

    def _restore_before(self, step: int) -> int | None:
        """The restore that a run of error starting at `step` follows: a restore before action r puts state row r back
        (a difference there shows at step r - 1) and steps from it (step r)."""
        return next((r for r in sorted(self.replayed.restored_at, reverse=True) if step in (r - 1, r)), None)

    def _restore_reason(self) -> str:
        if self.ctx.resync:
            return f"--resync {self.ctx.resync}"
        return "the episode has no seed, so the replay starts from its recorded initial state"

    def _restore_difference(self) -> Cause | None:
        onset = self.explanation.onset
        if onset is None or self.one_step is None:
            return None
        restored = self._restore_before(onset.step)
        if restored is None:
            return None
        at_onset = _worst_at(self.one_step, max(onset.step, 0))
        return Cause("restore_difference", f"a restored state: the difference began in the first step after the replay "
                     f"restored the recorded state (step {restored}, {self._restore_reason()}), where one step from a "
                     "restored state is known to differ from the uninterrupted run; it stays within step mode's "
                     "tolerances", step=self.step, key=self.cmp.first_divergence.key,
                     evidence=[onset.describe(), f"one step from the restored state {max(onset.step, 0)}: "
                               + (at_onset.describe() if at_onset.error > 0 else "exact"), self._one_step_fine()])

    # -- 6. the actions in another control mode
    def _other_control_mode(self) -> Cause | None:
        """When no step around k gives its recorded state from the restored one (the actions do not produce the
        recorded states), whether they do in another of the robot's control modes that takes actions of the recorded
        size: a recording that names the wrong control mode (a ManiSkill file's sidecar, say)."""
        window = self._window()
        if self.one_step is None or not all(_worst_at(self.one_step, t, only="env_states/").ratio > 1 for t in window):
            return None
        named, modes = self.replayer.u.control_mode, self.replayer.same_size_control_modes()
        first = self.recorded.first_steps(window[-1] + 1)
        for mode in modes:
            try:
                stepped = self.replayer.in_control_mode(mode).replay(first, mode="step", obs=False).episode
            except Exception:  # noqa: BLE001 - a mode the recorded state cannot be restored into reproduces nothing
                continue
            one = compare_episode(first, stepped, Tolerances.for_mode("step"), channels=self.ctx.channels)
            worst = max((_worst_at(one, t) for t in window), key=lambda w: w.ratio)
            if worst.ratio <= 1:
                return Cause("control_mode_differs", f"control mode differs: the recorded actions give the recorded "
                             f"states in {mode}, not in {named}, the control mode the recording names", step=self.step,
                             key=self.cmp.first_divergence.key, evidence=[
                                 f"steps {_listed(window)}, each from its restored state: not reproduced in {named} "
                                 f"({_worst_at(self.one_step, self.step).describe()} at step {self.step}), reproduced "
                                 f"in {mode} (" + (f"largest: {worst.describe()}" if worst.error else "exactly") + ")",
                                 f"replay it in {mode}: name that control mode in the recording (a ManiSkill file: its "
                                 "JSON sidecar's env_kwargs and each episode's control_mode)"])
        self.checked.append(f"one step from each restored state in the robot's other control modes with actions of the "
                            f"recorded size ({_listed(modes) or 'none'}): none reproduces steps {_listed(window)}")
        return None

    def _window(self, k: int | None = None) -> list[int]:
        """Step k (None: the divergent step) and its `NEIGHBOURS` on each side that the episode has."""
        k = self.step if k is None else k
        return [t for t in range(k - NEIGHBOURS, k + NEIGHBOURS + 1) if 0 <= t < self.recorded.length]

    # -- 7.
    def _undetermined(self) -> Cause:
        """No cause the data supports: what was found, from what was actually checked."""
        onset, k = self.explanation.onset, self.step
        found = ["the scene matches" if self.replayed.scene_differences is not None else
                 "the scene was not compared (the recording has no fingerprint)"]
        evidence = []
        if not self.has_states:
            found.append("the file holds no states")
            evidence.append(_NO_STATES)
        elif self.unexplained is not None:
            found.append(self.unexplained.found)
            evidence += self.unexplained.evidence
        elif k >= 0:
            evidence.append(self._one_step_fine())
            share = self._share_of_divergence()
            if self.one_step is not None and (share is None or share < SHARE_OF_DIVERGENCE):
                found.append("each step alone reproduces the recording")
            elif self.one_step is not None:
                found.append(f"step {k} alone is within step mode's tolerances but as far off as the divergence")
        if k >= 0 and self.has_states and self.steps_on:
            found.append("the difference did not start at float noise nor right after a restore")
        if onset is not None:
            evidence.append(onset.describe())
        elif compares_states(self.cmp):
            evidence.append("the state matched the recording up to the divergence")
        return Cause("undetermined", "undetermined: " + ", ".join(found) + "; checked: " + "; ".join(self.checked),
                     step=k, key=self.cmp.first_divergence.key, evidence=evidence)


def _listed(items: list[Any]) -> str:
    return ", ".join(map(str, items))


def _other_episode(recorded: Episode) -> Episode | None:
    """`recorded` with its reset moved to another episode of the same scene (None: its scene cannot be rebuilt)."""
    meta = another_episode(recorded.meta)
    return None if meta is None else dataclasses.replace(recorded, meta=meta)


def _state_difference(a: dict[str, Any], b: dict[str, Any], tol: Tolerances) -> _Worst:
    """The largest difference (relative to `tol`) between two flat states (key path → (1, ...) arrays)."""
    worst = _Worst(-1, "", 0.0, 1.0)
    for path in sorted(set(a) & set(b)):
        x, y = np.asarray(a[path]), np.asarray(b[path])
        if x.shape != y.shape:
            return _Worst(-1, f"env_states/{path}", math.inf, 0.0)
        for comp in components_of(path, x.shape[1:]):
            err = float(component_error(x, y, comp)[0])
            cand = _Worst(-1, comp.key, err, tol[comp.group])
            if cand.ratio > worst.ratio:
                worst = cand
    return worst


def explain_divergence(replayer: EpisodeReplayer, recorded: Episode, replayed: ReplayedEpisode, cmp: EpisodeComparison,
                       ctx: ExplainContext) -> Explanation | None:
    """The explanation of `cmp`'s first divergence (None when the replay did not diverge). Uses `replayer` for the
    one-step errors and resets (its env is left reset to another point of the episode)."""
    if cmp.first_divergence is None:
        return None
    return _Explainer(replayer, recorded, replayed, cmp, ctx).run()
