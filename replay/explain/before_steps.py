"""The causes found before any step is compared (the module order of `simreel.replay.explain.explain`, items 1 and
2): another scene or build, a recorded quaternion that is no rotation, a reset that is not reproducible or not the
recorded one."""

from __future__ import annotations

from typing import Any

import numpy as np

from simreel.model.components import Tolerances, components_of, format_number, not_rotations
from simreel.replay.explain.case import NO_STATES, Case
from simreel.replay.explain.worst import state_difference
from simreel.sim.fingerprint import SceneDifference
from simreel.sim.state import state_row
from simreel.verdicts.divergence import Cause

__all__ = ["scene_cause", "build_cause", "no_rotation_cause", "reset_cause"]

_SCENE_LINES = 8


def scene_cause(case: Case) -> Cause | None:
    """``scene_differs`` where the replaying scene's fingerprint differs from the recording's."""
    diffs: list[SceneDifference] | None = case.replayed.scene_differences
    if diffs is None:
        case.checked.append("scene fingerprint: not compared (the recording has none)")
        diffs = []
    else:
        case.checked.append(f"scene fingerprint compared at the reset: {len(diffs)} difference(s)")
    return _differs("scene", [d.describe() for d in diffs] + list(case.ctx.build_differences) if diffs else [])


def build_cause(case: Case) -> Cause | None:
    """Other versions, sim backend or sim config: named when no step-level cause was found (a Python patch release
    beside an altered action is not the reason)."""
    return _differs("build (versions, sim backend or sim config)", list(case.ctx.build_differences))


def _differs(what: str, lines: list[str]) -> Cause | None:
    if not lines:
        return None
    more = [f"... {len(lines) - _SCENE_LINES} more"] if len(lines) > _SCENE_LINES else []
    return Cause("scene_differs", f"the replaying {what} differs from the recorded one ({lines[0]}), found at the "
                 "reset before any step was compared; a replay of another scene is expected to diverge",
                 step=None, key=None, evidence=lines[:_SCENE_LINES] + more)


def no_rotation_cause(case: Case) -> Cause | None:
    """The first recorded quaternion that is no rotation (its norm off 1: zeroed, scaled; `not_rotations`): data no
    simulator wrote, so the file is what is off, whatever else differs."""
    for path, rows in case.recorded.env_states.items():
        for comp in components_of(path, rows.shape[1:]):
            if not comp.quat:
                continue
            bad = np.flatnonzero(not_rotations(np.asarray(rows[:, comp.start:comp.stop], np.float64)))
            if bad.size:
                row, q = int(bad[0]), rows[int(bad[0]), comp.start:comp.stop]
                norm = format_number(float(np.linalg.norm(np.asarray(q, np.float64))))
                return Cause("input_inconsistent", f"input inconsistent: the recording's {comp.key} at state row "
                             f"{row} is [{', '.join(format_number(float(x)) for x in q)}], no rotation (norm {norm}); no "
                             "simulator writes that: the file was damaged or altered", step=case.step, key=comp.key,
                             evidence=[f"{bad.size} state row(s) of {comp.key} hold no rotation, the first row {row}"])
    return None


def reset_cause(case: Case) -> Cause | None:
    """For a divergence at the reset: two more resets with the recorded seed and options, against each other
    (``reset_not_reproducible``) and against the recorded initial state (``input_inconsistent``)."""
    ep = case.recorded.meta
    first = case.replayer.initial_state(ep)
    second = case.replayer.initial_state(ep)
    tol = Tolerances.for_mode("states")
    again = state_difference(first, second, tol)
    case.checked.append(f"reset twice with seed {ep.seed} and the recorded options")
    how = f"seed {ep.seed}" + (f" and options {ep.reset_options}" if ep.reset_options else "")
    if again.ratio > 1:
        return Cause("reset_not_reproducible", f"the task's reset is not reproducible: two resets with {how} give "
                     f"different states ({again.describe_states()}), so it draws from something the seed does not "
                     "set (torch or numpy's global RNG, say)", step=-1, key=again.key,
                     evidence=[f"reset 1 vs reset 2: {again.describe_states()}"] + _reset_vs_recorded(case, first))
    if not case.has_states:
        case.checked.append(NO_STATES)
        return None
    recorded = state_difference(state_row(case.recorded.env_states, 0), first, tol)
    if recorded.ratio > 1:
        return Cause("input_inconsistent", f"input inconsistent with the recording at the reset: {how} gives the same "
                     f"initial state twice, but not the recorded one ({recorded.describe_states()})", step=-1,
                     key=recorded.key, evidence=[f"reset 1 vs reset 2: {again.describe_states()}",
                                                 f"reset vs the recording: {recorded.describe_states()}"])
    return None


def _reset_vs_recorded(case: Case, reset: dict[str, Any]) -> list[str]:
    if not case.has_states:
        return ["reset 1 vs the recording: not compared (the file holds no states)"]
    recorded = state_difference(state_row(case.recorded.env_states, 0), reset, Tolerances.for_mode("states"))
    return [f"reset 1 vs the recording: {recorded.describe_states()}"]
