"""Heterogeneous objects: a different actor or articulation in each sub-scene, seen as one object.

ManiSkill builds such objects by hand (see its PickSingleYCB and OpenCabinetDrawer tasks): build one
object per sub-scene with ``set_scene_idxs([i])``, merge them with `Actor.merge` / `Articulation.merge`,
then swap the per-env parts in the state-dict registry for the merged view. Forgetting the swap (as
several built-in tasks do) makes the state dict hold ``obj-0``, ``obj-1``, ... so its keys depend on
``num_envs``; merging articulations of different DOF makes its shape depend on which objects were drawn.
The helpers here do all of it in one call::

    from simreel.authoring.heterogeneous import build_heterogeneous_actor

    def _load_scene(self, options):
        kinds = self._batched_episode_rng.choice(["box", "ball"])   # one draw per sub-scene

        def add_shapes(builder, i):                   # called once per sub-scene i
            if kinds[i] == "box":
                builder.add_box_collision(half_size=[0.02] * 3)
                builder.add_box_visual(half_size=[0.02] * 3)
            else:
                builder.add_sphere_collision(radius=0.02)
                builder.add_sphere_visual(radius=0.02)

        self.obj = build_heterogeneous_actor(self.scene, add_shapes, name="obj",
                                             initial_pose=sapien.Pose(p=[0, 0, 0.02]))

After it, ``scene.state_dict_registry`` holds ``obj`` (one row per sub-scene) and not ``obj-0``, ...;
``scene.actors`` still holds the parts (ManiSkill needs them), ``scene.actor_views["obj"]`` the view.

For articulations, `build_heterogeneous_articulation` also pads qpos/qvel in the state to a fixed
``state_dof`` (an articulation's state is ``13 + 2 * DOF`` floats: root pose and velocities, then qpos,
then qvel, each of qpos/qvel zero-padded to ``state_dof``), and merges named links so that e.g.
``cabinet.links_map["handle"].joint.qpos`` reads the handle joint of every sub-scene.

This module imports mani_skill, sapien and torch only when a helper is called.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from simreel.errors import HeterogeneousBuildError

__all__ = [
    "HeterogeneousBuildError",
    "build_heterogeneous_actor",
    "build_heterogeneous_articulation",
    "merge_actors",
    "merge_articulations",
]



def build_heterogeneous_actor(
    scene: Any,
    build_part: Callable[[Any, int], Any],
    *,
    name: str,
    initial_pose: Any = None,
    body_type: str = "dynamic",
) -> Any:
    """Build one actor per sub-scene and return their merged, registered view.

    ``build_part(builder, i)`` adds the shapes of sub-scene ``i`` to a fresh ``scene.create_actor_builder()``
    whose ``initial_pose`` is already ``initial_pose`` (it may change it). The parts are named
    ``f"{name}-{i}"``; the merged view, named ``name``, replaces them in the state-dict registry.
    """
    parts = []
    for i in range(scene.num_envs):
        builder = scene.create_actor_builder()
        builder.set_scene_idxs([i])
        builder.initial_pose = _default_pose(initial_pose)
        build_part(builder, i)
        builder.set_physx_body_type(body_type)
        parts.append(builder.build(name=f"{name}-{i}"))
    return merge_actors(parts, name=name)


def build_heterogeneous_articulation(
    scene: Any,
    build_part: Callable[[Any, int], Any],
    *,
    name: str,
    fix_root_link: bool = True,
    initial_pose: Any = None,
    **merge: Any,
) -> Any:
    """Build one articulation per sub-scene and return their merged, registered, padded view.

    ``build_part(builder, i)`` creates the links of sub-scene ``i`` in a fresh
    ``scene.create_articulation_builder()`` (``builder.create_link_builder(parent)``, ``set_name``,
    ``set_joint_properties``...). `merge` are `merge_articulations`' ``state_dof`` (required) and
    ``merged_links``.
    """
    parts = []
    for i in range(scene.num_envs):
        builder = scene.create_articulation_builder()
        builder.set_scene_idxs([i])
        builder.initial_pose = _default_pose(initial_pose)
        build_part(builder, i)
        parts.append(builder.build(name=f"{name}-{i}", fix_root_link=fix_root_link))
    return merge_articulations(parts, name=name, **merge)


def merge_actors(parts: Sequence[Any], *, name: str) -> Any:
    """`Actor.merge` the parts under ``name`` and put the merged view in the state-dict registry in
    place of the parts. Use it when the parts are built by other code than `build_heterogeneous_actor`."""
    from mani_skill.utils.structs import Actor

    if not parts:
        raise HeterogeneousBuildError(f"merge_actors({name!r}) got no parts; build one part per sub-scene")
    scene = parts[0].scene
    _unregister(scene, parts)
    merged = Actor.merge(list(parts), name=name)
    scene.add_to_state_dict_registry(merged)
    return merged


def merge_articulations(
    parts: Sequence[Any],
    *,
    name: str,
    state_dof: int | None,
    merged_links: Sequence[str] = (),
) -> Any:
    """Merge articulations (possibly of different DOF) under ``name`` and register the merged view.

    ``state_dof``: the DOF the state is padded to, the largest DOF any part of this task can have, so
    that the state shape ``(num_envs, 13 + 2 * state_dof)`` is the same for every seed and ``num_envs``.
    ``None`` is allowed only when every part has the same DOF (then the state is ManiSkill's own).

    ``merged_links``: link names that every part has; each is merged with `Link.merge` into
    ``merged.links_map[link_name]`` (its ``.joint`` is the merged parent joint, ``.joint.qpos`` has shape
    ``(num_envs,)``).
    """
    import torch

    if not parts:
        raise HeterogeneousBuildError(f"merge_articulations({name!r}) got no parts; build one per sub-scene")
    dofs = [int(obj.dof) for part in parts for obj in part._objs]
    if state_dof is None:
        if len(set(dofs)) > 1:
            raise HeterogeneousBuildError(
                f"parts of {name!r} have DOF {sorted(set(dofs))}: the state shape would depend on which parts "
                f"were drawn; pass state_dof=<largest DOF this task can build> (e.g. {max(dofs)} or more)"
            )
    elif max(dofs) > state_dof:
        raise HeterogeneousBuildError(
            f"a part of {name!r} has {max(dofs)} DOF, more than state_dof={state_dof}; raise state_dof to "
            f"the largest DOF the task can build"
        )
    for link_name in merged_links:
        missing = [part.name for part in parts if link_name not in part.links_map]
        if missing:
            raise HeterogeneousBuildError(
                f"cannot merge link {link_name!r} of {name!r}: parts {missing} have no such link "
                f"(they have {sorted(parts[0].links_map)}); give the link that name in every part"
            )

    scene = parts[0].scene
    _unregister(scene, parts)
    cls = _padded_articulation_class()
    merged = cls.create_from_physx_articulations(
        [obj for part in parts for obj in part._objs],
        scene,
        torch.concat([part._scene_idxs for part in parts]),
        _merged=True,
        _process_links=False,
    )
    merged.name = name
    merged.state_dof = state_dof
    scene.articulation_views[name] = merged  # what Articulation.merge does
    # ManiSkill leaves `links` / `links_map` of a merged articulation empty (its parts' links differ);
    # list the root and the merged links there, so code that walks `art.links` finds them
    merged.links_map = {merged.root.name: merged.root}
    for link_name in merged_links:
        from mani_skill.utils.structs import Link

        parts_links = [part.links_map[link_name] for part in parts]
        merged.links_map[link_name] = Link.merge(parts_links, name=link_name)
    merged.links = list(merged.links_map.values())
    scene.add_to_state_dict_registry(merged)
    return merged


def _unregister(scene: Any, parts: Sequence[Any]) -> None:
    from mani_skill.utils.structs import Articulation

    registry = scene.state_dict_registry
    for part in parts:
        table = registry.articulations if isinstance(part, Articulation) else registry.actors
        if table.get(part.name) is part:
            scene.remove_from_state_dict_registry(part)


def _default_pose(pose: Any) -> Any:
    if pose is not None:
        return pose
    import sapien

    return sapien.Pose()


_PADDED_CLASS = None


def _padded_articulation_class():
    """A ManiSkill `Articulation` whose state pads qpos and qvel to ``state_dof`` (built on first use)."""
    global _PADDED_CLASS
    if _PADDED_CLASS is not None:
        return _PADDED_CLASS
    import numpy as np
    import torch
    from mani_skill.utils.structs import Articulation

    class PaddedArticulation(Articulation):
        """Merged articulation with a fixed state width ``13 + 2 * state_dof``."""

        state_dof: int | None = None

        def get_state(self):
            state = super().get_state()
            pad = self._state_pad()
            if pad == 0:
                return state
            m = self.max_dof
            zeros = torch.zeros((state.shape[0], pad), dtype=state.dtype, device=state.device)
            return torch.hstack([state[:, : 13 + m], zeros, state[:, 13 + m :], zeros])

        def set_state(self, state, env_idx=None):
            pad = self._state_pad()
            if pad:
                m, d = self.max_dof, self.state_dof
                head, qvel = state[..., : 13 + m], state[..., 13 + d : 13 + d + m]
                if isinstance(state, torch.Tensor):
                    state = torch.cat([head, qvel], dim=-1)
                else:
                    state = np.concatenate([head, qvel], axis=-1)
            super().set_state(state, env_idx)

        def _state_pad(self) -> int:
            return 0 if self.state_dof is None else self.state_dof - self.max_dof

    _PADDED_CLASS = PaddedArticulation
    return _PADDED_CLASS
