"""What a ManiSkill scene holds, by the names its state dict uses.

The state dict is keyed by ManiSkill's state-dict *registry*, which for heterogeneous tasks holds merged
views (`peg`) rather than the per-sub-scene parts (`peg_0`, ...). simreel names bodies the same way
everywhere: `<actor>` or `<articulation>/<link>`. Takes the unwrapped env; imports nothing heavy.
"""

from __future__ import annotations

from typing import Any

__all__ = ["describe_scene", "named_bodies", "dynamic_actor_names"]


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
