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

The case and its context: `simreel.replay.explain.case`; items 1 and 2: `before_steps`; item 3: `one_step` and
`step_causes`; items 4 to 6: `growth`; the error measures: `worst`.
"""

from __future__ import annotations

from simreel.model.episode import Episode
from simreel.replay.explain.before_steps import build_cause, no_rotation_cause, reset_cause, scene_cause
from simreel.replay.explain.case import NO_STATES, Case, ExplainContext
from simreel.replay.explain.growth import amplification, other_control_mode, restore_difference
from simreel.replay.explain.one_step import SHARE_OF_DIVERGENCE, OneStepCheck
from simreel.replay.run.engine import EpisodeReplayer, ReplayedEpisode
from simreel.verdicts.compare import EpisodeComparison
from simreel.verdicts.divergence import Cause, Explanation, compares_states

__all__ = ["ExplainContext", "explain_divergence"]


def explain_divergence(replayer: EpisodeReplayer, recorded: Episode, replayed: ReplayedEpisode, cmp: EpisodeComparison,
                       ctx: ExplainContext) -> Explanation | None:
    """The explanation of `cmp`'s first divergence (None when the replay did not diverge). Uses `replayer` for the
    one-step errors and resets (its env is left reset to another point of the episode)."""
    if cmp.first_divergence is None:
        return None
    case = Case(replayer, recorded, replayed, cmp, ctx)
    check = OneStepCheck(case)
    scene = scene_cause(case) or no_rotation_cause(case)
    if case.step < 0:
        cause = scene or reset_cause(case)
    else:
        cause = (scene or check.cause() or amplification(case, check) or restore_difference(case, check)
                 or other_control_mode(case, check))
    case.explanation.cause = cause or build_cause(case) or _undetermined(case, check)
    return case.explanation


def _undetermined(case: Case, check: OneStepCheck) -> Cause:
    """No cause the data supports: what was found, from what was actually checked."""
    onset, k = case.explanation.onset, case.step
    found = ["the scene matches" if case.replayed.scene_differences is not None else
             "the scene was not compared (the recording has no fingerprint)"]
    evidence = []
    if not case.has_states:
        found.append("the file holds no states")
        evidence.append(NO_STATES)
    elif check.unexplained is not None:
        found.append(check.unexplained.found)
        evidence += check.unexplained.evidence
    elif k >= 0:
        evidence.append(check.fine_text())
        share = check.share_of_divergence()
        if check.one_step is not None and (share is None or share < SHARE_OF_DIVERGENCE):
            found.append("each step alone reproduces the recording")
        elif check.one_step is not None:
            found.append(f"step {k} alone is within step mode's tolerances but as far off as the divergence")
    if k >= 0 and case.has_states and case.steps_on:
        found.append("the difference did not start at float noise nor right after a restore")
    if onset is not None:
        evidence.append(onset.describe())
    elif compares_states(case.cmp):
        evidence.append("the state matched the recording up to the divergence")
    return Cause("undetermined", "undetermined: " + ", ".join(found) + "; checked: " + "; ".join(case.checked),
                 step=k, key=case.cmp.first_divergence.key, evidence=evidence)
