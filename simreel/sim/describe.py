"""Describe a live ManiSkill env: its `RecordingMeta` (everything needed to rebuild it and judge a replay)
and what its scene holds, by the names its state dict uses.

The state dict is keyed by ManiSkill's state-dict *registry*, which for heterogeneous tasks holds merged
views (`peg`) rather than the per-sub-scene parts (`peg_0`, ...). simreel names bodies the same way
everywhere: `<actor>` or `<articulation>/<link>`. Functions take the (possibly wrapped) env or its
unwrapped env as named; nothing heavy is imported at module level.
"""

from __future__ import annotations

import dataclasses
import datetime
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.errors import UsageError
from simreel.model.meta import RecordingMeta, new_recording_id
from simreel.model.state_tree import flatten, layout_of
from simreel.sim.make import EnvConfig, env_versions

__all__ = [
    "recording_meta",
    "action_space_json",
    "max_episode_steps_of",
    "flatten_obs",
    "sim_config_json",
    "describe_scene",
    "named_bodies",
    "dynamic_actor_names",
    "SceneBody",
    "scene_bodies",
]


def max_episode_steps_of(env: Any) -> int | None:
    """The time limit the wrapper stack enforces (ManiSkill's TimeLimitWrapper or gymnasium's)."""
    e = env
    while e is not None:
        limit = getattr(e, "_max_episode_steps", None)
        if limit is not None:
            return int(limit)
        e = getattr(e, "env", None)
    spec = getattr(env, "spec", None)
    return getattr(spec, "max_episode_steps", None)


def flatten_obs(obs: Any, obs_mode: str) -> dict[str, Any]:
    """Observations as flat key paths; a bare tensor observation is stored under its obs mode's name."""
    if isinstance(obs, dict):
        return flatten(obs)
    return flatten({obs_mode: obs})


def sim_config_json(cfg: Any) -> dict[str, Any]:
    """An env's `sim_config` (a dataclass in ManiSkill 3, a dict or None elsewhere) as plain JSON-able data."""
    if dataclasses.is_dataclass(cfg):
        return dataclasses.asdict(cfg)
    return dict(cfg or {})


def recording_meta(env: Any, **recorder_fields: Any) -> RecordingMeta:
    """Describe `env` (a gym.make'd ManiSkill env, possibly wrapped) as recording metadata.

    The scene fingerprint is that of sub-scene 0 as it is now (`simreel.sim.fingerprint`).
    `recorder_fields` are the `RecordingMeta` fields only the recorder knows (``contact_channels``,
    ``info_layout``, ``obs_layout``, ``pose_bodies``, ``imports``, ``command``); they are set as given.
    """
    from simreel.sim.fingerprint import scene_fingerprint

    u = env.unwrapped
    spec = getattr(u, "spec", None) or getattr(env, "spec", None)
    env_id = spec.id if spec is not None else type(u).__name__
    make_kwargs = dict(getattr(spec, "kwargs", {}) or {})
    return RecordingMeta(
        env_id=env_id,
        env_kwargs={k: v for k, v in make_kwargs.items() if k not in EnvConfig.names()},
        obs_mode=u.obs_mode,
        control_mode=u.control_mode,
        reward_mode=u.reward_mode,
        sim_backend=u.backend.sim_backend,
        render_backend=u.backend.render_backend,
        num_envs=int(u.num_envs),
        max_episode_steps=max_episode_steps_of(env),
        control_freq=float(u.control_freq),
        sim_freq=float(u.sim_freq),
        sim_config=sim_config_json(u.sim_config),
        action_space=action_space_json(env_id, u.single_action_space),
        state_layout=layout_of(flatten(u.get_state_dict()), batched=True),
        scene=describe_scene(u),
        versions=env_versions(),
        scene_fingerprint=scene_fingerprint(u),
        created_utc=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        recording_id=new_recording_id(),
        **recorder_fields,
    )


def action_space_json(env_id: str, space: Any) -> dict[str, Any]:
    """One env's Box action space as `RecordingMeta.action_space` holds it; `UsageError` for any other space."""
    if space.shape is None:
        raise UsageError(
            f"{env_id} has a {type(space).__name__} action space (a multi-agent task); simreel records "
            "single-agent tasks with Box action spaces for now"
        )
    return {"shape": list(space.shape), "dtype": str(space.dtype), "low": space.low.tolist(),
            "high": space.high.tolist()}


# ----------------------------------------------------------------------------------------- the scene
def _scene_idxs(obj: Any) -> list[int]:
    idxs = getattr(obj, "_scene_idxs", None)
    return [int(i) for i in idxs.tolist()] if idxs is not None else []


def describe_scene(unwrapped: Any) -> dict[str, Any]:
    """Registry actors/articulations with body type, sub-scene indices and whether they are merged views.

    `merged` marks registry entries that are not themselves in `scene.actors`/`scene.articulations`
    (a task built per-sub-scene parts and registered their merge).
    """
    scene = unwrapped.scene
    reg = scene.state_dict_registry
    actors = {
        name: {
            "body_type": str(getattr(a, "px_body_type", "")),
            "scene_idxs": _scene_idxs(a),
            "merged": name not in scene.actors,
        }
        for name, a in reg.actors.items()
    }
    arts = {
        name: {
            "links": [link.name for link in art.links],
            "dof": int(getattr(art, "dof", [0])[0]) if hasattr(getattr(art, "dof", None), "__getitem__") else None,
            "max_dof": int(getattr(art, "max_dof", 0)),
            "scene_idxs": _scene_idxs(art),
            "merged": name not in scene.articulations,
        }
        for name, art in reg.articulations.items()
    }
    unregistered = sorted(set(scene.actors) - set(reg.actors)) + sorted(set(scene.articulations) - set(reg.articulations))
    return {"actors": actors, "articulations": arts, "not_in_state_dict": unregistered, "num_envs": unwrapped.num_envs}


def named_bodies(unwrapped: Any) -> dict[str, Any]:
    """`{"cube": Actor, "panda/panda_hand": Link, ...}` for every registry actor and articulation link."""
    reg = unwrapped.scene.state_dict_registry
    out: dict[str, Any] = dict(reg.actors)
    for art_name, art in reg.articulations.items():
        for link in art.links:
            out[f"{art_name}/{link.name}"] = link
    return out


def dynamic_actor_names(unwrapped: Any) -> list[str]:
    """Registry actors that move (neither static nor kinematic)."""
    reg = unwrapped.scene.state_dict_registry
    return [n for n, a in reg.actors.items() if str(getattr(a, "px_body_type", "")) == "dynamic"]


# ------------------------------------------------------------------------------------ bodies of a sub-scene
@dataclass
class SceneBody:
    """One body of the rebuilt sub-scene: its simreel name and the sapien entity that carries its pose."""

    name: str
    entity: Any
    body_type: str
    """``static``, ``kinematic``, ``dynamic`` (actors) or ``link``."""
    group: str
    """``robot`` (a link of the agent), ``articulation`` (another articulation's link) or ``actor``."""
    in_registry: bool = True
    """False for bodies not in the state-dict registry (their poses are never recorded)."""


def _slot(obj: Any, env_idx: int) -> int | None:
    """Position of sub-scene `env_idx` among a ManiSkill struct's per-sub-scene objects (None: absent)."""
    idxs = getattr(obj, "_scene_idxs", None)
    if idxs is None:
        return 0 if env_idx == 0 else None
    where = np.nonzero(np.asarray(idxs.tolist()) == env_idx)[0]
    return int(where[0]) if len(where) else None


def _agent_articulations(unwrapped: Any) -> set[str]:
    agent = getattr(unwrapped, "agent", None)
    if agent is None:
        return set()
    agents = list(agent.agents) if hasattr(agent, "agents") else [agent]
    return {a.robot.name for a in agents if getattr(a, "robot", None) is not None}


class _BodyList:
    """Bodies in the order they are found, each entity once."""

    def __init__(self) -> None:
        self.bodies: list[SceneBody] = []
        self._seen: set[int] = set()

    def add(self, name: str, entity: Any, body_type: str, group: str, in_registry: bool) -> None:
        if entity.global_id not in self._seen:
            self._seen.add(entity.global_id)
            self.bodies.append(SceneBody(name, entity, body_type, group, in_registry))

    def actors(self, actors: dict[str, Any], env_idx: int, *, in_registry: bool) -> None:
        for name, actor in actors.items():
            k = _slot(actor, env_idx)
            if k is not None:
                self.add(name, actor._objs[k], str(getattr(actor, "px_body_type", "dynamic")), "actor", in_registry)

    def articulation(self, art_name: str, art: Any, env_idx: int, group: str) -> None:
        k = _slot(art, env_idx)
        if k is None:
            return
        for link in art.links:
            lk = _slot(link, env_idx)
            if lk is not None:
                self.add(f"{art_name}/{link.name}", link._objs[lk].entity, "link", group, True)
        # links that only this sub-scene's part of a merged articulation has
        for physx_link in art._objs[k].links:
            self.add(f"{art_name}/{physx_link.entity.name}", physx_link.entity, "link", group, False)


def scene_bodies(unwrapped: Any, *, env_idx: int = 0) -> list[SceneBody]:
    """Every body of sub-scene `env_idx` of a live ManiSkill env, named as simreel names them: registry actors,
    registry articulations' links (also those only one part of a merged articulation has), then the actors
    that are not in the state dict."""
    scene = unwrapped.scene
    reg = scene.state_dict_registry
    robots = _agent_articulations(unwrapped)
    found = _BodyList()
    found.actors(reg.actors, env_idx, in_registry=True)
    for art_name, art in reg.articulations.items():
        found.articulation(art_name, art, env_idx, "robot" if art_name in robots else "articulation")
    found.actors(scene.actors, env_idx, in_registry=False)
    return found.bodies
