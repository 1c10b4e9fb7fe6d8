"""The one-step check (item 3 of `simreel.replay.explain.explain`'s order): one step from each restored recorded
state around the divergent step, in the replaying env and in a second instance reset to another episode first, and
the cause those errors support (`OneStepCheck`; the causes themselves: `simreel.replay.explain.step_causes`)."""

from __future__ import annotations

import dataclasses

from simreel.model.components import Tolerances, format_number
from simreel.model.episode import Episode
from simreel.replay.explain import step_causes
from simreel.replay.explain.case import NO_STATES, Case
from simreel.replay.explain.step_causes import Unexplained
from simreel.replay.explain.worst import COMPUTED, Worst, listed, worst_at
from simreel.sim.rebuild import another_episode
from simreel.verdicts.compare import EpisodeComparison, compare_episode
from simreel.verdicts.divergence import Cause

__all__ = ["OneStepCheck", "SHARE_OF_DIVERGENCE"]

SHARE_OF_DIVERGENCE = 0.5
"""A value the task computes that one step from a restored state puts off by at least this share of the replay's own
divergence on the same key, the state after the step reproduced within the replay's tolerances, is off whatever step
mode's (looser) tolerance says: a one-step error as large as the divergence itself is not a reproduction."""


class OneStepCheck:
    """The one-step errors of a `Case` (`one_step`: None until measured, or where they could not be) and what they
    tell: `cause`, else what was found without a cause (`unexplained`)."""

    def __init__(self, case: Case) -> None:
        self.case = case
        self.one_step: EpisodeComparison | None = None
        self.between: EpisodeComparison | None = None
        self.other_seed: int | None = None
        self.no_second: str | None = None
        """Why there is no second instance (None: there is one, or the one-step errors were not measured)."""
        self.unexplained: Unexplained | None = None

    def cause(self) -> Cause | None:
        """The cause the one-step errors show at the divergent step, else at the onset of the state difference when
        that lies before the steps checked around it."""
        case = self.case
        if not case.has_states:
            case.checked.append(NO_STATES)
            return None
        self._measure()
        if self.one_step is None:
            return None
        cause = self._cause_at(case.step, case.cmp.first_divergence.key)
        onset = case.explanation.onset
        if cause is None and onset is not None and 0 <= onset.step < case.window()[0]:
            cause = self._cause_at(onset.step, onset.key)
            if cause is not None:
                cause.evidence.append(f"the state began to differ there ({onset.describe()}), before step {case.step} "
                                      "where the replay left its tolerance")
        return cause

    def _stepped(self, episode: Episode) -> Episode | None:
        """`episode` replayed in step mode (None, with a note, where that fails)."""
        try:
            return self.case.replayer.replay(episode, mode="step", obs=False).episode
        except Exception as exc:  # noqa: BLE001 - a failed check is reported, the replay's verdict stands
            self.case.checked.append(f"one-step errors: not measured ({type(exc).__name__}: {exc})")
            return None

    def _measure(self) -> None:
        """A: one step from each restored state, the env reset to the episode (``--mode step``; in that mode the
        replay's own comparison); B: the same with the env reset to another episode of the same scene first. A vs the
        recording says whether a transition is reproduced; A vs B whether it depends on what the env held before the
        restore (state the dict lacks)."""
        case, tol = self.case, Tolerances.for_mode("step")
        own = case.ctx.mode == "step"
        a = case.replayed.episode if own and case.replayed.episode is not None else self._stepped(case.recorded)
        if a is None:
            return
        self.one_step = case.cmp if own else compare_episode(case.recorded, a, tol, channels=case.ctx.channels)
        meta = another_episode(case.recorded.meta)
        if meta is None:
            self.no_second = ("no second instance: the episode's scene cannot be rebuilt for certain (built by an "
                              "unseeded reset, or the file does not say whether its reset rebuilt it)")
            case.checked.append(self.no_second)
            return
        b = self._stepped(dataclasses.replace(case.recorded, meta=meta))
        if b is not None:
            self.between = compare_episode(a, b, tol, channels=case.ctx.channels)
            self.other_seed = meta.seed

    def _cause_at(self, k: int, key: str) -> Cause | None:
        """The cause the one-step errors around step k support (see the module's item 3), or None."""
        case, steps = self.case, self.case.window(k)
        worst = {t: self.worst(self.one_step, t) for t in steps}
        how = "the replay's own (--mode step)" if case.ctx.mode == "step" else \
            "restore state t, step action t; step tolerances"
        case.checked.append(f"one-step errors ({how}) at steps {listed(steps)}")
        apart = None
        if self.between is not None:
            case.checked.append(f"the same after resetting to another episode (seed {self.other_seed}) first, step {k}")
            apart = self.worst(self.between, k)
        off = [t for t in steps if worst[t].ratio > 1]
        if apart is not None and apart.ratio > 1:
            return step_causes.state_not_captured(self, k, key, worst, apart)
        if k not in off:
            return None
        physics = worst_at(self.one_step, k, only="env_states/")
        if off == [k]:
            return step_causes.inconsistent_step(self, k, key, worst, apart)
        if off == [k, k + 1] and physics.ratio > 1:
            return step_causes.inconsistent_state_row(self, k, key, worst, apart)
        if off == steps and all(worst_at(self.one_step, t, only="env_states/").ratio <= 1 for t in steps):
            return step_causes.task_differs(self, k, key, worst, apart)
        self.unexplained = Unexplained(
            f"steps {listed(off)} are not reproduced from their restored states",
            [f"steps {listed(off)} are not reproduced from their restored states"
             + (", whatever the env held before the restore" if apart is not None else "")
             + f" ({worst[k].describe()} at step {k})"
             + (f"; steps {listed([t for t in steps if t not in off])} are" if len(off) < len(steps) else ""),
             "not decided what differs there: the recorded actions or states, the physics, or a tolerance tighter "
             "than one step from a restored state holds could each do that", *self.second_instance(k, apart)])
        return None

    def worst(self, cmp: EpisodeComparison, step: int) -> Worst:
        """`worst_at`, with the divergent key also judged against the divergence itself (`SHARE_OF_DIVERGENCE`)."""
        worst, share = worst_at(cmp, step), self._divergence_share(cmp, step)
        return share if share is not None and share.ratio > worst.ratio else worst

    def _divergence_share(self, cmp: EpisodeComparison, step: int) -> Worst | None:
        """The divergent key at `step` of `cmp` judged by `SHARE_OF_DIVERGENCE` of the divergence's error, where it is a
        value the task computes and the state after the step is reproduced within the replay's own tolerances (else
        None: a state off by more than those explains a computed value off too)."""
        d = self.case.cmp.first_divergence
        if not d.key.startswith(COMPUTED) or d.key.startswith("obs/") or d.key not in cmp.errors or not d.error > 0:
            return None
        err = cmp.errors[d.key]
        if not 0 <= step < len(err) or not self._state_within_verdict(cmp, step):
            return None
        return Worst(step, d.key, float(err[step]), SHARE_OF_DIVERGENCE * d.error,
                     judged_by=f"{format_number(SHARE_OF_DIVERGENCE)} × the replay's divergence,")

    def _state_within_verdict(self, cmp: EpisodeComparison, step: int) -> bool:
        """Whether every state key of `cmp` after `step` is within the tolerance the replay's verdict used."""
        verdict = self.case.cmp.tolerance
        keys = [key for key in cmp.errors if key.startswith("env_states/") and key in verdict]
        return bool(keys) and all(float(cmp.errors[key][step + 1]) <= float(verdict[key]) for key in keys)

    def second_instance(self, k: int, apart: Worst | None) -> list[str]:
        """The line on the second instance at step k: what it gave, or why it could not run."""
        if apart is not None:
            return [f"an instance reset to another episode (seed {self.other_seed}) before the restore gives the same "
                    "step " + (f"(largest difference: {apart.describe()})" if apart.error else "exactly")]
        if self.no_second is not None:
            return [f"whether step {k} depends on what the env held before the restore was not checked: "
                    f"{self.no_second}"]
        return []

    def fine_text(self) -> str:
        """The one-step check at the divergent step, with how large its error on the divergent key is beside the
        replay's own divergence: within step mode's tolerances but as large as the divergence is no reproduction."""
        if self.one_step is None:
            return "one-step errors not measured"
        step = self.case.step
        w = worst_at(self.one_step, step)
        share = self.share_of_divergence()
        found = w.describe() if w.error > 0 else "exactly"
        if share is not None and share >= SHARE_OF_DIVERGENCE:
            return f"step {step} alone is within step mode's tolerances ({found}), but {self._divergence_part()}"
        said = f"step {step} alone reproduces the recording ({found})"
        return said + (f"; {self._divergence_part()}" if share is not None else "")

    def share_of_divergence(self) -> float | None:
        """The one-step error at the divergent step on the divergent key over the divergence's own error (None: not
        measured, or no error to compare with)."""
        d = self.case.cmp.first_divergence
        row = self.case.step + 1 if d.key.startswith(("env_states/", "obs/")) else self.case.step
        if self.one_step is None or d.key not in self.one_step.errors or not d.error > 0:
            return None
        err = self.one_step.errors[d.key]
        return float(err[row]) / d.error if 0 <= row < len(err) else None

    def _divergence_part(self) -> str:
        d, share = self.case.cmp.first_divergence, self.share_of_divergence()
        one = share * d.error
        return (f"one step alone puts {d.key} off by {format_number(one)}, {format_number(100 * share)}% of the replay's "
                f"own divergence there ({format_number(d.error)})")
