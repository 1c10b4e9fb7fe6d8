"""Read a CPU env's state dict straight from SAPIEN, without ManiSkill's per-object torch round trips.

ManiSkill 3.0.1's `get_state_dict()` builds a `Pose` and several torch tensors per object (~240 µs for
PickCube, a fifth of a CPU step). On the CPU sim with one env the same numbers are plain attributes of
the SAPIEN entities; `FastStateReader` reads them into numpy (~30 µs). It is used only where it gives the
very same values: a task that does not override `get_state_dict` (or only adds declared custom state
through `simreel.custom_state.CustomStateMixin`), registry objects of ManiSkill's own `Actor` /
`Articulation` classes, CPU sim, `num_envs == 1`. Its users (the recorder, the replay engine) check it
bit for bit against `get_state_dict()` with `matches()` and fall back to `get_state_dict()` on any
difference.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simreel.state_tree import flatten, to_numpy

__all__ = ["FastStateReader"]


def _base_get_state_dict() -> tuple[Any, ...]:
    from mani_skill.envs.sapien_env import BaseEnv

    from simreel.custom_state import CustomStateMixin

    return BaseEnv.get_state_dict, CustomStateMixin.get_state_dict


class FastStateReader:
    """`read()` → flat state dict (key path → (1, ...) float32 array) of a supported CPU env."""

    def __init__(self, unwrapped: Any) -> None:
        from mani_skill.utils.structs import Actor, Articulation

        u = unwrapped
        self.u = u
        self._actors: list[tuple[str, Any, Any, bool]] = []
        self._arts: list[tuple[str, Any, Any]] = []
        reg = u.scene.state_dict_registry
        for name, actor in reg.actors.items():
            if type(actor) is not Actor or len(actor._objs) != 1:
                raise TypeError(name)
            kind = actor.px_body_type
            if kind == "static":
                continue
            self._actors.append((f"actors/{name}", actor._objs[0], actor._bodies[0], kind == "dynamic"))
        for name, art in reg.articulations.items():
            if type(art) is not Articulation or len(art._objs) != 1 or art.max_dof != art._objs[0].dof:
                raise TypeError(name)
            root = art.root
            self._arts.append((f"articulations/{name}", art._objs[0], root._bodies[0]))
        self._custom = type(u).get_state_dict is _base_get_state_dict()[1]

    @classmethod
    def for_env(cls, unwrapped: Any) -> FastStateReader | None:
        """A reader for `unwrapped`, or None where only `get_state_dict()` gives the right answer."""
        from mani_skill.envs.scene import ManiSkillScene

        u = unwrapped
        if getattr(u, "gpu_sim_enabled", True) or int(u.num_envs) != 1:
            return None
        if type(u).get_state_dict not in _base_get_state_dict():
            return None
        if type(u.scene).get_sim_state is not ManiSkillScene.get_sim_state:
            return None
        try:
            return cls(u)
        except (TypeError, AttributeError, IndexError):
            return None

    def read(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        zeros = np.zeros(3, np.float32)
        for key, entity, body, dynamic in self._actors:
            pose = entity.pose
            if dynamic:
                v, w = body.linear_velocity, body.angular_velocity
            else:
                v = w = zeros
            out[key] = np.concatenate([pose.p, pose.q, v, w]).astype(np.float32, copy=False)[None]
        for key, px_art, root in self._arts:
            pose = root.entity_pose
            out[key] = np.concatenate(
                [pose.p, pose.q, root.linear_velocity, root.angular_velocity, px_art.qpos, px_art.qvel]
            ).astype(np.float32, copy=False)[None]
        u = self.u
        agent = getattr(u, "agent", None)
        if agent is not None:
            controller = agent.get_controller_state()
            if isinstance(agent.controller, dict):
                controller = {k: v for k, v in controller.items() if len(v) > 0}
            if len(controller) > 0:
                out.update(flatten({"controller": controller}))
        if self._custom:
            from simreel.custom_state import get_custom_state

            out.update({k: to_numpy(v) for k, v in get_custom_state(u).items()})
        return out

    def matches(self) -> bool:
        """Whether `read()` equals `get_state_dict()` now, bit for bit, key for key."""
        fast, slow = self.read(), flatten(self.u.get_state_dict())
        if list(fast) != list(slow) and set(fast) != set(slow):
            return False
        return all(
            fast[k].shape == slow[k].shape and fast[k].dtype == slow[k].dtype and np.array_equal(fast[k], slow[k])
            for k in slow
        )
