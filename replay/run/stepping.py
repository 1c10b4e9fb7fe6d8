"""How a block replay drives each step and stores what it gives: the step of each mode (``actions``, ``states``,
``step``) and the outcome of a step or a reset (rewards, flags, info, contact forces, state, observations, body
poses) written into the block's buffers (`simreel.replay.run.blocks.BlockBuffers`).

`BlockStepping` is a part of `simreel.replay.run.engine.EpisodeReplayer` (a base class of it): it works on the
replayer's env (``u``), fast state reader, contact sampler, observation mode and body poses."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from simreel.model.blocks import StepBlock
from simreel.model.state_tree import to_numpy
from simreel.replay.run.blocks import BlockBuffers
from simreel.sim.state import read_state, restore_state

if TYPE_CHECKING:
    from simreel.replay.run.engine import _Run

__all__ = ["BlockStepping"]


def _scalar(x: Any) -> Any:
    """The one value of env 0 in a scalar, (1,) tensor or array (`.item()` is the cheap way for tensors)."""
    if isinstance(x, (bool, int, float)):
        return x
    try:
        return x.item()
    except (AttributeError, ValueError, RuntimeError):
        return to_numpy(x).reshape(-1)[0]


def _flag(info: dict[str, Any], key: str) -> bool:
    return bool(_scalar(info[key])) if key in info else False


class BlockStepping:
    """The steps of a block replay and the rows they write (`EpisodeReplayer`'s; see the module)."""

    def _step_actions(self, run: _Run, buf: BlockBuffers, i: int, action: Any) -> None:
        t = run.states.first + i
        if run.resync and t and t % run.resync == 0:
            restore_state(self.u, run.states.row(t), elapsed_steps=t)
            run.out.restored_at.append(t)
        self._after_step(buf, i, self._step(action))

    def _step_restored(self, run: _Run, buf: BlockBuffers, i: int, action: Any) -> None:
        t = run.states.first + i
        if t or run.source.meta.initial_state_known:  # else step 0 starts from the reproduced reset
            restore_state(self.u, run.states.row(t), elapsed_steps=t)
        self._after_step(buf, i, self._step(action))

    def _step_states(self, run: _Run, buf: BlockBuffers, i: int, action: Any) -> None:
        u, states, t = self.u, run.states, run.states.first + i
        restore_state(u, states.row(t), elapsed_steps=t)
        # one step from the recorded state t, for its contacts and the controller's target; without the
        # observation `step` would compute (with cameras: a frame rendered for nothing, half the time)
        u._step_action(action)
        contacts = self._contacts.sample()[0] if buf.contact_forces is not None else None
        restore_state(u, states.row(t + 1), elapsed_steps=t + 1)
        info = u.get_info()
        obs = u.get_obs(info, unflattened=True) if self.obs_mode != "none" else {}
        reward = u.get_reward(obs=obs, action=action[None], info=info)
        terminated = _flag(info, "success") or _flag(info, "fail")
        truncated = self.max_episode_steps is not None and t + 1 >= self.max_episode_steps
        self._after_step(buf, i, (None, reward, terminated, truncated, info))
        if contacts is not None:
            buf.contact_forces[i] = contacts
        if self.need_obs:
            buf.set_obs(i, self._obs(u._flatten_raw_obs(obs) if obs else u.get_obs(info)))

    def _state(self) -> dict[str, np.ndarray]:
        if self._fast is not None:
            return self._fast.read()
        return read_state(self.u)

    def _obs(self, obs: Any) -> dict[str, np.ndarray]:
        from simreel.sim.describe import flatten_obs

        return {p: a[0] for p, a in flatten_obs(obs, self.obs_mode).items()}

    def _block(self, recorded: StepBlock, actions: np.ndarray | None = None) -> BlockBuffers:
        """Buffers for the replay of the recorded block (`actions`: what is stepped, if not the recorded actions)."""
        return BlockBuffers(recorded, actions, n_channels=len(self.meta.contact_channels) if self._contacts else 0,
                      n_poses=len(self.pose_bodies))

    def _after_step(self, buf: BlockBuffers, i: int, outcome: tuple[Any, Any, Any, Any, Any]) -> None:
        """Store the outcome ``(obs, reward, terminated, truncated, info)`` of the block's step i and the state after it."""
        obs, reward, terminated, truncated, info = outcome
        buf.rewards[i] = _scalar(reward)
        buf.terminated[i] = _scalar(terminated)
        buf.truncated[i] = _scalar(truncated)
        buf.success[i] = _flag(info, "success")
        buf.fail[i] = _flag(info, "fail")
        for key, dst in buf.info.items():
            value = info.get(key)
            if value is not None:
                dst[i] = _scalar(value)
                buf.info_returned.add(key)
        if buf.contact_forces is not None:
            buf.contact_forces[i] = self._contacts.sample()[0]
        self._after_state(buf, i, obs)

    def _after_state(self, buf: BlockBuffers, i: int, obs: Any) -> None:
        """Store the state the env holds now (and its observation and body poses) as the block's per-state row i."""
        buf.set_state(i, self._state())
        if self.need_obs and obs is not None:
            buf.set_obs(i, self._obs(obs))
        if buf.body_poses is not None:
            buf.body_poses[i] = self._poses()

    def _poses(self) -> np.ndarray:
        from simreel.sim.poses import sample_body_poses

        return sample_body_poses(self.u, self.pose_bodies)[0]

    def _reset_row(self, recorded: StepBlock) -> StepBlock:
        """The replay's row 0 (state, observations, body poses right after its reset), laid out like `recorded`."""
        buf = self._block(recorded)
        self._after_state(buf, 0, self.u.get_obs() if self.need_obs else None)
        return buf.block()

    def _actions(self, actions: np.ndarray) -> Any:
        import torch

        return torch.from_numpy(np.ascontiguousarray(actions)).to(self.u.device)

    def _step(self, action: Any) -> tuple[Any, Any, Any, Any, Any]:
        """`unwrapped.step` plus the time limit (what ManiSkill's TimeLimitWrapper adds), without the wrapper stack."""
        obs, reward, terminated, _, info = self.u.step(action)
        limit = self.max_episode_steps
        truncated = limit is not None and self.u._elapsed_steps[0].item() >= limit
        return obs, reward, terminated, truncated, info
