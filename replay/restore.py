"""Restore a recorded state into a live env: all of it, not only what ManiSkill's `set_state_dict` takes.

ManiSkill 3.0.1's `BaseEnv.set_state_dict` restores actors and articulations (and, through a task's
override such as `simreel.custom_state.CustomStateMixin`, custom task keys) but ignores the
``controller`` entry that `get_state_dict` returns for target-based control modes
(``pd_ee_target_delta_pos``, ``pd_joint_target_delta_pos``, ...): the controller keeps the target of the
env's own last step. `restore_state` also hands the controller its saved targets, and sets the episode's
elapsed step count, which the time limit and ``info["elapsed_steps"]`` read.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.state_tree import unflatten

__all__ = ["restore_state", "state_row"]


def state_row(env_states: Mapping[str, np.ndarray], t: int) -> dict[str, np.ndarray]:
    """Row t of flat (T+1, ...) state arrays, each with a batch dimension of 1."""
    return {p: a[t : t + 1] for p, a in env_states.items()}


def _to_torch(tree: Any, device: Any) -> Any:
    import torch

    if isinstance(tree, Mapping):
        return {k: _to_torch(v, device) for k, v in tree.items()}
    return torch.as_tensor(np.array(tree), device=device)  # a copy: controllers may modify targets in place


def restore_state(unwrapped: Any, flat_state: Mapping[str, np.ndarray], *, elapsed_steps: int | None = None) -> None:
    """Put the env into the recorded state `flat_state` (key path → (1, ...) array).

    Calls the task's `set_state_dict` (actors, articulations, custom keys), then the agent's
    `set_controller_state` with the saved ``controller`` entry, and sets the elapsed step count when given.
    """
    u = unwrapped
    state = _to_torch(unflatten(flat_state), u.device)
    u.set_state_dict(state)
    controller = state.get("controller")
    agent = getattr(u, "agent", None)
    if controller and agent is not None:
        agents = getattr(agent, "agents_dict", None)  # MultiAgent: one controller state per robot uid
        if agents is not None:
            for uid, sub in controller.items():
                if uid in agents and sub:
                    agents[uid].set_controller_state(sub)
        else:
            agent.set_controller_state(controller)
    if elapsed_steps is not None:
        u._elapsed_steps[...] = int(elapsed_steps)
