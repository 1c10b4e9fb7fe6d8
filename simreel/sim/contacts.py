"""Contact forces per step: net force on every moving body, and pairwise forces for named pairs.

On the CPU sim every channel comes from one pass over `px.get_contacts()` (ManiSkill's own per-body
calls each walk the whole contact list, ~18 µs per body). On the GPU sim it uses ManiSkill's batched
contact queries, which ManiSkill creates once and caches. Signs follow ManiSkill: a pair channel
`a:b` is the force on `a` from `b`, i.e. `scene.get_pairwise_contact_forces(a, b)`.
"""

from __future__ import annotations

from array import array
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
        self._n = int(unwrapped.num_envs)
        self._px = unwrapped.scene.px
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
            self._hits: dict[tuple[Any, Any], list[tuple[int, float]]] = {}
            self._zeros = np.zeros((1, len(self.channels), 3), np.float32)
            self._zeros.flags.writeable = False

    def sample(self) -> np.ndarray:
        if not self.channels:
            return np.zeros((self._n, 0, 3), np.float32)
        if self._gpu:
            return self._sample_gpu(self._n)
        contacts = self._px.get_contacts()
        if not contacts:  # many steps of many tasks touch nothing
            return self._zeros
        out = [0.0] * (3 * len(self.channels))
        self._add_impulses(out, contacts)
        timestep = self._px.timestep
        return np.frombuffer(array("f", [v / timestep for v in out]), np.float32).reshape(self._zeros.shape)

    def _add_impulses(self, out: list[float], contacts: list[Any]) -> None:
        """Add each contact's impulse (the sum over its points) to the channels of its bodies (`out`: x, y, z of
        channel c at 3c), with ManiSkill's sign.

        In Python floats, not numpy: a step touches a few contacts, and each numpy call on arrays of 3 costs more
        than the arithmetic (~20 µs each right after a physics step). The numbers are numpy's, bit for bit: a
        contact's points are summed in float32 row by row (`_point_sum`), the channels add them up in float64, and
        `sample` divides by the timestep in float64 and rounds to float32 (through `array("f")`: C's conversion,
        as numpy's).
        """
        hits_of = self._hits
        for contact in contacts:
            b0, b1 = contact.bodies
            hits = hits_of.get((b0, b1))
            if hits is None:
                hits = hits_of[(b0, b1)] = self._channels_of(b0, b1)
            if not hits:  # a contact no channel records (between two static bodies, ...)
                continue
            points = contact.points
            if not points:
                continue
            x, y, z = _point_sum(points)
            for at, sign in hits:  # sign * x is exact, and a + (-b) is a - b
                out[at] += sign * x
                out[at + 1] += sign * y
                out[at + 2] += sign * z

    def _channels_of(self, b0: Any, b1: Any) -> list[tuple[int, float]]:
        """Where a contact between bodies b0 and b1 adds its impulse: (3 × channel, sign), in ManiSkill's signs."""
        net, pairs = self._net_index, self._pair_index
        hits = [(c, 1.0) for c in net.get(b0, ())] + [(c, -1.0) for c in net.get(b1, ())]
        for pair, sign in (((b0, b1), 1.0), ((b1, b0), -1.0)):
            c = pairs.get(pair)
            if c is not None:
                hits.append((c, sign))
        return [(3 * c, sign) for c, sign in hits]


def _point_sum(points: list[Any]) -> tuple[float, float, float]:
    """The impulses of a contact's points summed in float32 row by row, as numpy adds (3,) float32 arrays (and
    `np.sum(axis=0)` sums rows), held in Python floats: the double sum of two float32 values, rounded to float32
    (through `array("f")`, C's conversion), is their float32 sum, since a double has more than 2 × 24 + 2 bits."""
    x, y, z = points[0].impulse.tolist()
    for point in points[1:]:
        a, b, c = point.impulse.tolist()
        x, y, z = array("f", (x + a, y + b, z + c))
    return x, y, z
