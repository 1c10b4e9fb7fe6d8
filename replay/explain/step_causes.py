"""The causes the one-step errors can show at a step k (`simreel.replay.explain.one_step.OneStepCheck` decides which
applies): the recorded step k or the state after it is not what the action gives (``input_inconsistent``), the task
computes something else from the same state (``task_differs``), or the step depends on what the env held before the
restore (``state_not_captured``). Each takes the check, step k, the divergent key, the worst key of each step of the
window (`worst`) and that of the second instance at k (`apart`; None: there is none)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from simreel.replay.explain.worst import COMPUTED, Worst, listed, worst_at
from simreel.verdicts.divergence import Cause

if TYPE_CHECKING:
    from simreel.replay.explain.one_step import OneStepCheck

__all__ = ["inconsistent_step", "inconsistent_state_row", "task_differs", "state_not_captured", "Unexplained"]

_Steps = dict[int, Worst]


@dataclass(frozen=True)
class Unexplained:
    """What the one-step check found without deciding a cause: a phrase for the summary and its evidence lines."""

    found: str
    evidence: list[str]


def _at(k: int, worst: _Steps) -> str:
    return f"step {k} from the exactly restored state {k}: " + (worst[k].describe() if worst[k].error else "exact")


def _reproduced(worst: _Steps, off: list[int]) -> str:
    """The line on the steps of the window that reproduce the recording."""
    fine = [w for t, w in worst.items() if t not in off]
    largest = max(fine, key=lambda w: w.ratio, default=None)
    tail = f" (largest: {largest.describe()})" if largest is not None and largest.error > 0 else " (exactly)"
    return f"steps {listed([w.step for w in fine]) or 'none'} reproduce the recording from their restored " \
           f"states{tail}"


def _why_step_is_off(k: int, physics: Worst, worst: Worst, length: int) -> str:
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


def inconsistent_step(check: OneStepCheck, k: int, key: str, worst: _Steps, apart: Worst | None) -> Cause:
    """Only step k is off: the recording's step k is not what its action gives (the worst state key at k says which
    part)."""
    physics = worst_at(check.one_step, k, only="env_states/")
    why = _why_step_is_off(k, physics, worst[k], check.case.recorded.length)
    evidence = [_at(k, worst), _reproduced(worst, [k]), *check.second_instance(k, apart)]
    return Cause("input_inconsistent", f"input inconsistent with the recording at step {k}: " + why, step=k,
                 key=key, evidence=evidence)


def inconsistent_state_row(check: OneStepCheck, k: int, key: str, worst: _Steps, apart: Worst | None) -> Cause:
    """Steps k and k + 1 off, the rest reproduced: the recorded state after step k (row k + 1) is what is off: step k
    does not give it, and the step from it does not give the next recorded state."""
    case = check.case
    evidence = [_at(k, worst), f"step {k + 1} from the recorded state {k + 1}: {worst[k + 1].describe()}",
                _reproduced(worst, [k, k + 1])]
    later = worst_at(case.cmp, k + 1, only="env_states/")
    confirmed = case.steps_on and k + 1 not in case.replayed.restored_at and later.ratio <= 1
    if confirmed:
        evidence.append(f"the replay, which stepped on from its own state {k + 1} rather than the recorded one, "
                        f"gives the recorded state {k + 2} (" + ("exactly" if later.error == 0 else
                                                                 f"largest: {later.describe_states()}") + ")")
    evidence += check.second_instance(k, apart)
    alternative = "" if confirmed else f" (or actions {k} and {k + 1} both are)"
    return Cause("input_inconsistent", f"input inconsistent with the recording at step {k}: the recorded state after "
                 f"step {k} (state row {k + 1}) is not what action {k} gives from the exactly restored state {k}, "
                 f"and the step from it does not give the recorded state {k + 2}, while the steps around them "
                 f"reproduce the recording: that state row is off{alternative}", step=k, key=key, evidence=evidence)


def task_differs(check: OneStepCheck, k: int, key: str, worst: _Steps, apart: Worst | None) -> Cause | None:
    """Every step checked reproduces the state but not what the task computes from it: with a second instance that
    agrees, the task computes something else from the same state than was recorded (``task_differs``); without one,
    that cannot be told from state the dict lacks (left undetermined, naming both, in `check.unexplained`)."""
    steps = list(worst)
    computed = worst_at(check.one_step, k, only=COMPUTED)
    evidence = [_at(k, worst), f"at every step checked ({listed(steps)}) the state after the step is "
                f"reproduced, but not what the task computes from it ({computed.describe()} at step {k})"]
    if apart is None:
        check.unexplained = Unexplained(
            f"what the task computes is off at every step checked ({listed(steps)}) while the state is reproduced: "
            "its code or build (a reward, evaluate(), the reward mode) differs from the recording's, or it depends "
            "on state its dict lacks; no second instance could tell which", [*evidence, *check.second_instance(k, None)])
        return None
    evidence += check.second_instance(k, apart) + list(check.case.ctx.build_differences)
    return Cause("task_differs", "task differs: from the same state the task computes something else than was "
                 f"recorded ({computed.key}), at every step checked and alike in an instance that held another "
                 "episode, so no missing state explains it: the task's code or build (its reward, evaluate(), the "
                 "reward mode) differs from the recording's, or the recorded values were altered", step=k, key=key,
                 evidence=evidence)


def state_not_captured(check: OneStepCheck, k: int, key: str, worst: _Steps, apart: Worst) -> Cause:
    """The step from a restored state depends on what the env held before the restore: two instances restored to the
    same state and given the same action disagree."""
    evidence = [_at(k, worst)]
    physics = worst_at(check.one_step, k, only="env_states/")
    computed = worst_at(check.one_step, k, only=COMPUTED)
    if physics.ratio <= 1 and computed.ratio > 1:
        evidence.append(f"the state after step {k} is reproduced ("
                        + (f"largest: {physics.describe()}" if physics.error > 0 else "exactly")
                        + f"), but not what the task computes from it: {computed.describe()}")
    evidence.append(f"restored into an instance reset to another episode (seed {check.other_seed}) first, step {k} "
                    f"differs: {apart.describe()} between the two")
    evidence += [f"step {t}: {w.describe()}" for t, w in worst.items() if t != k and w.ratio > 1]
    evidence.append(f"find the state the task keeps outside its state dict with `simreel audit {check.case.ctx.env_id}` "
                    "(--trajectory to audit along this recording)")
    return Cause("state_not_captured", f"state not captured: restoring the recorded state does not reproduce step {k}, "
                 "which depends on state the task's state dict does not hold", step=k, key=key, evidence=evidence)
