"""The causes found when each step alone reproduces the recording, or none does (items 4 to 6 of
`simreel.replay.explain.explain`'s order): a float-noise difference that grew (``amplification``), one that came
from a restore (``restore_difference``), and actions that belong to another control mode (``control_mode_differs``)."""

from __future__ import annotations

from simreel.model.components import Tolerances, format_number
from simreel.replay.explain.case import Case
from simreel.replay.explain.one_step import OneStepCheck
from simreel.replay.explain.worst import listed, worst_at
from simreel.verdicts.compare import compare_episode
from simreel.verdicts.divergence import Cause

__all__ = ["amplification", "restore_difference", "other_control_mode"]

_CONTACT_EVENTS = ("contact_begins", "contact_ends", "grasp_begins", "grasp_ends")


def amplification(case: Case, check: OneStepCheck) -> Cause | None:
    """The state first differed by float noise and grew at least tenfold before the divergent step."""
    onset = case.explanation.onset
    # no onset where every step started from a restored state (`steps_on`): nothing grows across steps there
    if onset is None or not onset.float_noise or not onset.growth >= 10 or onset.step >= case.step:  # NaN: no ratio
        return None
    contacts = [e for e in case.explanation.events if onset.step <= e.step <= case.step and e.kind in _CONTACT_EVENTS]
    where = "after reset" if onset.step < 0 else f"at step {onset.step}"
    via = "through " + ", ".join(e.describe() for e in contacts[:3]) if contacts else \
        "with no contact beginning or ending on the way"
    restored = _restore_before(case, onset.step)
    evidence = [onset.describe(), check.fine_text()]
    if restored is not None:
        evidence.append(f"the replay restored the recorded state before step {restored} ({_restore_reason(case)})")
    return Cause("amplification", f"amplification of a tiny difference: the state first differed {where} by "
                 f"{format_number(onset.error)} (float noise) and grew {format_number(onset.growth)}× {via}, until "
                 f"{case.cmp.first_divergence.key} left its tolerance at step {case.step}", step=case.step,
                 key=case.cmp.first_divergence.key, evidence=evidence)


def _restore_before(case: Case, step: int) -> int | None:
    """The restore that a run of error starting at `step` follows: a restore before action r puts state row r back
    (a difference there shows at step r - 1) and steps from it (step r)."""
    return next((r for r in sorted(case.replayed.restored_at, reverse=True) if step in (r - 1, r)), None)


def _restore_reason(case: Case) -> str:
    if case.ctx.resync:
        return f"--resync {case.ctx.resync}"
    return "the episode has no seed, so the replay starts from its recorded initial state"


def restore_difference(case: Case, check: OneStepCheck) -> Cause | None:
    """The difference began in the first step after a restore, within step mode's tolerances."""
    onset = case.explanation.onset
    if onset is None or check.one_step is None:
        return None
    restored = _restore_before(case, onset.step)
    if restored is None:
        return None
    at_onset = worst_at(check.one_step, max(onset.step, 0))
    return Cause("restore_difference", f"a restored state: the difference began in the first step after the replay "
                 f"restored the recorded state (step {restored}, {_restore_reason(case)}), where one step from a "
                 "restored state is known to differ from the uninterrupted run; it stays within step mode's "
                 "tolerances", step=case.step, key=case.cmp.first_divergence.key,
                 evidence=[onset.describe(), f"one step from the restored state {max(onset.step, 0)}: "
                           + (at_onset.describe() if at_onset.error > 0 else "exact"), check.fine_text()])


def other_control_mode(case: Case, check: OneStepCheck) -> Cause | None:
    """When no step around k gives its recorded state from the restored one (the actions do not produce the recorded
    states), whether they do in another of the robot's control modes that takes actions of the recorded size: a
    recording that names the wrong control mode (a ManiSkill file's sidecar, say)."""
    window = case.window()
    if check.one_step is None or not all(worst_at(check.one_step, t, only="env_states/").ratio > 1 for t in window):
        return None
    named, modes = case.replayer.u.control_mode, case.replayer.same_size_control_modes()
    first = case.recorded.first_steps(window[-1] + 1)
    for mode in modes:
        try:
            stepped = case.replayer.in_control_mode(mode).replay(first, mode="step", obs=False).episode
        except Exception:  # noqa: BLE001 - a mode the recorded state cannot be restored into reproduces nothing
            continue
        one = compare_episode(first, stepped, Tolerances.for_mode("step"), channels=case.ctx.channels)
        worst = max((worst_at(one, t) for t in window), key=lambda w: w.ratio)
        if worst.ratio <= 1:
            return Cause("control_mode_differs", f"control mode differs: the recorded actions give the recorded "
                         f"states in {mode}, not in {named}, the control mode the recording names", step=case.step,
                         key=case.cmp.first_divergence.key, evidence=[
                             f"steps {listed(window)}, each from its restored state: not reproduced in {named} "
                             f"({worst_at(check.one_step, case.step).describe()} at step {case.step}), reproduced "
                             f"in {mode} (" + (f"largest: {worst.describe()}" if worst.error else "exactly") + ")",
                             f"replay it in {mode}: name that control mode in the recording (a ManiSkill file: its "
                             "JSON sidecar's env_kwargs and each episode's control_mode)"])
    case.checked.append(f"one step from each restored state in the robot's other control modes with actions of the "
                        f"recorded size ({listed(modes) or 'none'}): none reproduces steps {listed(window)}")
    return None
