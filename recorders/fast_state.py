"""A faster, exact reader of `get_state_dict()` for stock ManiSkill tasks on the CPU sim.

ManiSkill's `get_state_dict()` builds every actor's 13 floats through torch Pose objects (~90-250 µs
a step for PickCube, most of the recorder's cost). On the CPU sim the same numbers sit in the PhysX
components, so this reads them directly. It applies only where nothing customises the state (the
task, scene, actors and articulations use ManiSkill's own `get_state*`), and it checks itself: at the
first step of every episode it compares its result with the real `get_state_dict()` bit for bit and
switches itself off for good on any difference.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from simreel.state_tree import flatten

__all__ = ["CpuStateReader"]


def _stock(u: Any) -> bool:
    from mani_skill.envs.sapien_env import BaseEnv
    from mani_skill.envs.scene import ManiSkillScene
    from mani_skill.utils.structs.actor import Actor
    from mani_skill.utils.structs.articulation import Articulation

    reg = u.scene.state_dict_registry
    return (
        not u.scene.gpu_sim_enabled
        and type(u).get_state_dict is BaseEnv.get_state_dict
        and type(u.scene).get_sim_state is ManiSkillScene.get_sim_state
        and all(type(a).get_state is Actor.get_state and len(a._objs) == 1 for a in reg.actors.values())
        and all(
            type(a).get_state is Articulation.get_state and len(a._objs) == 1 and a.max_dof == a._objs[0].dof
            for a in reg.articulations.values()
        )
    )


class CpuStateReader:
    """`read()` returns what `flatten(env.get_state_dict())` would, for a stock task on the CPU sim."""

    def __init__(self) -> None:
        self.enabled = True
        self._verify = False

    def bind(self, u: Any) -> None:
        """Call after every reset: the scene may have been rebuilt."""
        self._u = u
        if not self.enabled or not _stock(u):
            self.enabled = False
            return
        reg = u.scene.state_dict_registry
        self._actors = [
            (f"actors/{name}", a._bodies[0], a.px_body_type == "dynamic")
            for name, a in reg.actors.items()
            if a.px_body_type != "static"
        ]
        self._arts = [(f"articulations/{name}", a.root._objs[0], a._objs[0]) for name, a in reg.articulations.items()]
        self._verify = True

    def read(self) -> dict[str, np.ndarray]:
        u = self._u
        if not self.enabled:
            return flatten(u.get_state_dict())
        out: dict[str, np.ndarray] = {}
        for key, body, dynamic in self._actors:
            row = np.zeros((1, 13), np.float32)
            pose = body.entity_pose
            row[0, :3] = pose.p
            row[0, 3:7] = pose.q
            if dynamic:
                row[0, 7:10] = body.linear_velocity
                row[0, 10:13] = body.angular_velocity
            out[key] = row
        for key, root, px in self._arts:
            dof = px.dof
            row = np.empty((1, 13 + 2 * dof), np.float32)
            pose = root.entity_pose
            row[0, :3] = pose.p
            row[0, 3:7] = pose.q
            row[0, 7:10] = root.linear_velocity
            row[0, 10:13] = root.angular_velocity
            row[0, 13 : 13 + dof] = px.qpos
            row[0, 13 + dof :] = px.qvel
            out[key] = row
        controller = u.agent.get_controller_state()
        if isinstance(u.agent.controller, dict):
            controller = {k: v for k, v in controller.items() if len(v) > 0}
        if controller:
            out.update(flatten({"controller": controller}))
        if self._verify:
            self._verify = False
            self._check(out)
        return out

    def _check(self, fast: dict[str, np.ndarray]) -> None:
        real = flatten(self._u.get_state_dict())
        same = fast.keys() == real.keys() and all(
            fast[k].dtype == real[k].dtype and np.array_equal(fast[k], real[k]) for k in real
        )
        if not same:
            self.enabled = False
            diff = sorted(k for k in real.keys() | fast.keys() if k not in fast or k not in real
                          or not np.array_equal(fast[k], real[k]))
            warnings.warn(f"simreel: fast state reader disagrees with get_state_dict() on {diff}; "
                          "using get_state_dict() from now on", RuntimeWarning, stacklevel=3)
            fast.clear()
            fast.update(real)
