"""Declared custom task state: list it once, and the state dict carries it.

A ManiSkill task that samples something per episode outside the physics (a target height, a goal, a
difficulty level) must put it into `get_state_dict()` and read it back in `set_state_dict()`, or a
restored state silently disagrees with the episode it came from. ManiSkill's docs show a hand-written
override for that; `CustomStateMixin` replaces it with one declaration::

    from mani_skill.envs.sapien_env import BaseEnv
    from simreel.authoring.custom_state import CustomStateMixin

    class LiftCubeEnv(CustomStateMixin, BaseEnv):     # the mixin goes before BaseEnv
        custom_state = ("goal_height",)              # names of tensor attributes of the task

        def _initialize_episode(self, env_idx, options):
            ...
            self.goal_height[env_idx] = sampled_heights  # a tensor of shape (num_envs,)

Layout, as read by every other part of simreel:

- each declared name becomes a top-level key of the state dict, next to ManiSkill's ``"actors"`` and
  ``"articulations"``: ``state["goal_height"]`` is a clone of ``env.goal_height``;
- every declared attribute is a torch tensor batched over sub-scenes, of shape ``(num_envs,)`` (a scalar
  per sub-scene) or ``(num_envs, k)``, on the env's device (ManiSkill's flat state vectors allow no more);
- `set_state_dict(state, env_idx)` follows ManiSkill's convention for partial restores: the values in
  ``state`` hold one row per index in ``env_idx`` (all ``num_envs`` rows when ``env_idx`` is None), and
  only those rows of the attribute are overwritten;
- the flat `get_state()` / `set_state()` vectors carry the custom values too, after everything else, in
  declaration order (ManiSkill's own `set_state` would drop them; the mixin's does not).

A state dict that lacks a declared key is refused with `CustomStateError` rather than restored halfway.

This module imports neither torch nor mani_skill at import time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from simreel.errors import CustomStateError

__all__ = [
    "CustomStateMixin",
    "CustomStateError",
    "custom_state_names",
    "get_custom_state",
    "set_custom_state",
]



def custom_state_names(env: Any) -> tuple[str, ...]:
    """The custom state a task declares (``()`` for a task that declares none). Accepts a wrapped env."""
    names = getattr(getattr(env, "unwrapped", env), "custom_state", ())
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise CustomStateError(
            f"{type(env).__name__}.custom_state must be a tuple of attribute names, found {names!r}; "
            f'write e.g. custom_state = ("goal_height",)'
        )
    return tuple(names)


def _declared_tensor(env: Any, name: str):
    import torch

    if not hasattr(env, name):
        raise CustomStateError(
            f"{type(env).__name__} declares custom state {name!r} but has no attribute {name!r}; "
            f"set self.{name} to a tensor of shape (num_envs,) in _load_scene or _initialize_episode"
        )
    value = getattr(env, name)
    num_envs = env.num_envs
    if not isinstance(value, torch.Tensor) or value.ndim not in (1, 2) or value.shape[0] != num_envs:
        found = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
        raise CustomStateError(
            f"{type(env).__name__}.{name} must be a torch tensor of shape (num_envs,) or (num_envs, k) "
            f"with num_envs={num_envs} to be custom state, found {found}; keep one row per sub-scene"
        )
    return value


def get_custom_state(env: Any) -> dict[str, Any]:
    """Clones of the declared custom state tensors, keyed by name (what the mixin adds to the state dict)."""
    env = getattr(env, "unwrapped", env)
    return {name: _declared_tensor(env, name).clone() for name in custom_state_names(env)}


def set_custom_state(env: Any, state: Mapping[str, Any], env_idx: Any = None) -> None:
    """Write the declared custom state from ``state`` (a full state dict or just the custom keys).

    With ``env_idx`` (indices or a boolean mask over sub-scenes) only those rows are written, and
    ``state[name]`` holds one row per selected sub-scene, as in ManiSkill's `set_state_dict`. Values may
    be torch tensors or numpy arrays (e.g. read back from a file). Every value is checked before any is
    written.
    """
    for target, rows, value in _checked_custom_values(getattr(env, "unwrapped", env), state, env_idx):
        target[rows] = value


def _checked_custom_values(env: Any, state: Mapping[str, Any], env_idx: Any) -> list[tuple[Any, Any, Any]]:
    import torch

    writes = []
    for name in custom_state_names(env):
        if name not in state:
            raise CustomStateError(
                f"state dict has no {name!r}, custom state that {type(env).__name__} declares; the state was "
                f"saved without it (by an older task version or a hand-made dict): save it with "
                f"env.get_state_dict(), or re-record"
            )
        target = _declared_tensor(env, name)
        rows = (
            torch.arange(env.num_envs, device=target.device)
            if env_idx is None
            else _as_index(env_idx, target)
        )
        value = torch.as_tensor(state[name], device=target.device, dtype=target.dtype)
        expected = (len(rows), *target.shape[1:])
        if tuple(value.shape) != expected:
            if value.numel() != len(rows) * target[0].numel():
                raise CustomStateError(
                    f"state[{name!r}] has shape {tuple(value.shape)}, expected {expected} "
                    f"(one row per restored sub-scene, env_idx={_describe(env_idx)})"
                )
            value = value.reshape(expected)  # e.g. (n, 1) from a flat state vector for an (n,) attribute
        writes.append((target, rows, value))
    return writes


def _as_index(env_idx: Any, like):
    import torch

    idx = torch.as_tensor(env_idx, device=like.device)
    if idx.dtype == torch.bool:
        idx = torch.nonzero(idx).flatten()
    return idx.long().flatten()


def _describe(env_idx: Any) -> str:
    return str(env_idx.tolist()) if hasattr(env_idx, "tolist") else repr(env_idx)


class CustomStateMixin:
    """Adds the attributes named in ``custom_state`` to `get_state_dict()` and restores them in
    `set_state_dict()` (and in the flat `get_state()` / `set_state()`).

    Put it before `BaseEnv` in the bases. See the module docstring for the layout and the shapes.
    """

    custom_state: ClassVar[tuple[str, ...]] = ()
    """Names of tensor attributes (shape ``(num_envs,)`` or ``(num_envs, k)``) that are part of the task's state."""

    def get_state_dict(self):
        state = super().get_state_dict()
        state.update(get_custom_state(self))
        return state

    def set_state_dict(self, state, env_idx=None):
        writes = _checked_custom_values(self, state, env_idx)  # refuse a bad state before touching the sim
        super().set_state_dict(state, env_idx)
        for target, rows, value in writes:
            target[rows] = value

    def set_state(self, state, env_idx=None):
        # BaseEnv.set_state rebuilds only "actors" and "articulations" and would drop the custom values;
        # rebuild the whole dict from the layout of the first state dict instead (flatten order).
        self.set_state_dict(_unflatten_like(self._init_raw_state, state), env_idx)


def _unflatten_like(template: Mapping[str, Any], flat) -> dict[str, Any]:
    """Inverse of ManiSkill's `flatten_state_dict` for a dict laid out like ``template``."""
    out: dict[str, Any] = {}
    start = 0

    def walk(src: Mapping[str, Any], dst: dict[str, Any]) -> None:
        nonlocal start
        for key, value in src.items():
            if isinstance(value, Mapping):
                dst[key] = {}
                walk(value, dst[key])
            else:
                width = 1 if value.ndim == 1 else int(value[0].numel())
                dst[key] = flat[..., start : start + width]
                start += width

    walk(template, out)
    if start != flat.shape[-1]:
        raise CustomStateError(
            f"flat state has {flat.shape[-1]} values per env, the env's state dict layout has {start}; "
            f"the vector comes from a different task or task version"
        )
    return out
