"""Contact forces per step: net force on every moving body, and pairwise forces for named pairs.

On the CPU sim every channel comes from one pass over `px.get_contacts()` (ManiSkill's own per-body
calls each walk the whole contact list, ~18 µs per body). On the GPU sim it uses ManiSkill's batched
contact queries, which ManiSkill creates once and caches. Signs follow ManiSkill: a pair channel
`a:b` is the force on `a` from `b`, i.e. `scene.get_pairwise_contact_forces(a, b)`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simreel.episode import ContactChannel
from simreel.errors import ContactSpecError
from simreel.sim.describe import dynamic_actor_names, named_bodies

__all__ = ["contact_channels", "ContactSampler", "parse_pairs"]

_FINGER_HINTS = ("finger", "tip", "pad")


def parse_pairs(spec: str) -> list[tuple[str, str]]:
    """`"panda/panda_leftfinger:cube,a:b"` → [("panda/panda_leftfinger", "cube"), ("a", "b")]."""
    pairs = []
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        parts = item.split(":")
        if len(parts) != 2 or not all(parts):
            raise ContactSpecError(
                f"bad contact pair {item!r}: expected BODY_A:BODY_B, e.g. panda/panda_leftfinger:cube"
            )
        pairs.append((parts[0], parts[1]))
    return pairs


def _auto_pairs(unwrapped: Any) -> list[tuple[str, str]]:
    """The task's declared pairs, else each robot finger-like link × each dynamic actor."""
    declared = getattr(unwrapped, "simreel_contact_pairs", None)
    if declared:
        return [tuple(p.split(":")) if isinstance(p, str) else tuple(p) for p in declared]
    robots = [a.robot for a in _agents(unwrapped)]
    fingers = [
        f"{r.name}/{link.name}" for r in robots for link in r.links if any(h in link.name for h in _FINGER_HINTS)
    ]
    return [(f, actor) for f in fingers for actor in dynamic_actor_names(unwrapped)]


def _agents(unwrapped: Any) -> list[Any]:
    agent = getattr(unwrapped, "agent", None)
    if agent is None:
        return []
    return list(agent.agents) if hasattr(agent, "agents") else [agent]


def contact_channels(unwrapped: Any, spec: str | None) -> list[ContactChannel]:
    """The channels for a `--contacts` spec: "auto" (default), "none", or "A:B,..." pairs.

    Net channels cover every non-static registry actor and every articulation link; pair channels are
    the named (or automatic) pairs. Unknown body names raise ContactSpecError listing the known ones.
    """
    spec = "auto" if spec is None else spec.strip()
    if spec == "none":
        return []
    bodies = named_bodies(unwrapped)
    reg = unwrapped.scene.state_dict_registry
    net = [
        ContactChannel("net", (name,))
        for name in bodies
        if name not in reg.actors or str(getattr(reg.actors[name], "px_body_type", "")) != "static"
    ]
    pairs = _auto_pairs(unwrapped) if spec == "auto" else parse_pairs(spec)
    for pair in pairs:
        for name in pair:
            if name not in bodies:
                known = ", ".join(sorted(bodies))
                raise ContactSpecError(f"contact pair names unknown body {name!r}; known bodies: {known}")
    return net + [ContactChannel("pair", (a, b)) for a, b in pairs]


class ContactSampler:
    """Samples every channel after a step: `sample()` → (num_envs, C, 3) float32 newtons.

    Call `bind()` after each reset: a reconfiguring reset replaces the scene's bodies.
    """

    def __init__(self, channels: list[ContactChannel]) -> None:
        self.channels = channels
        self._u: Any = None

    def bind(self, unwrapped: Any) -> None:
        self._u = unwrapped
        bodies = named_bodies(unwrapped)
        self._objs = [[bodies[b] for b in ch.bodies] for ch in self.channels]
        self._gpu = bool(unwrapped.scene.gpu_sim_enabled)
        if not self._gpu:
            self._net_index = {}
            self._pair_index: dict[tuple[Any, Any], int] = {}
            for c, (ch, objs) in enumerate(zip(self.channels, self._objs, strict=True)):
                if ch.kind == "net":
                    self._net_index.setdefault(objs[0]._bodies[0], []).append(c)
                else:
                    self._pair_index[(objs[0]._bodies[0], objs[1]._bodies[0])] = c

    def sample(self) -> np.ndarray:
        u = self._u
        n = int(u.num_envs)
        if not self.channels:
            return np.zeros((n, 0, 3), np.float32)
        if self._gpu:
            return self._sample_gpu(n)
        out = np.zeros((len(self.channels), 3), np.float64)
        net, pairs = self._net_index, self._pair_index
        for contact in u.scene.px.get_contacts():
            points = contact.points
            if not points:
                continue
            b0, b1 = contact.bodies
            impulse = points[0].impulse
            for point in points[1:]:  # the same float32 sums as np.sum(axis=0) (row by row), without its overhead
                impulse = impulse + point.impulse
            for c in net.get(b0, ()):
                out[c] += impulse
            for c in net.get(b1, ()):
                out[c] -= impulse
            c = pairs.get((b0, b1))
            if c is not None:
                out[c] += impulse
            c = pairs.get((b1, b0))
            if c is not None:
                out[c] -= impulse
        out /= u.scene.px.timestep
        return out.astype(np.float32)[None]

    def _sample_gpu(self, n: int) -> np.ndarray:
        scene = self._u.scene
        cols = []
        for ch, objs in zip(self.channels, self._objs, strict=True):
            if ch.kind == "net":
                f = objs[0].get_net_contact_forces()
            else:
                f = scene.get_pairwise_contact_forces(objs[0], objs[1])
            full = np.zeros((n, 3), np.float32)
            full[objs[0]._scene_idxs.cpu().numpy()] = f.detach().cpu().numpy()
            cols.append(full)
        return np.stack(cols, axis=1)
