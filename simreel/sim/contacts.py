"""Contact forces per step: net force on every moving body, and pairwise forces for named pairs.

On the CPU sim every channel comes from one pass over `px.get_contacts()` (ManiSkill's own per-body
calls each walk the whole contact list, ~18 µs per body). On the GPU sim it uses ManiSkill's batched
contact queries, which ManiSkill creates once and caches. Signs follow ManiSkill: a pair channel
`a:b` is the force on `a` from `b`, i.e. `scene.get_pairwise_contact_forces(a, b)`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simreel.errors import ContactSpecError, UsageError
from simreel.model.meta import ContactChannel
from simreel.sim.describe import dynamic_actor_names, named_bodies
from simreel.sim.step_rows import ContactRows

__all__ = ["contact_channels", "contacts_spec", "ContactSampler", "parse_pairs"]

_FINGER_HINTS = ("finger", "tip", "pad")

Capture = tuple[list[tuple[list[tuple[int, float]], list[list[float]]]], float]
"""A step's contacts as `ContactSampler.capture` copies them out: ([(where each adds its impulse: (3 × channel,
sign), its points' impulses)], the timestep)."""


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
        if parts[0] == parts[1]:
            raise ContactSpecError(f"bad contact pair {item!r}: a body paired with itself")
        if tuple(parts) in pairs:
            raise ContactSpecError(f"contact pair {item!r} is named twice")
        pairs.append((parts[0], parts[1]))
    if not pairs:
        raise ContactSpecError(f"contacts {spec!r} names no pair; give auto, none or pairs like "
                               "panda/panda_leftfinger:cube")
    return pairs


def contacts_spec(contacts: Any) -> str | None:
    """The `contacts` option as one spec string: a string (or None) as it is, a list or tuple of "A:B" pairs joined
    with "," (the natural form from Python). Anything else is `UsageError` saying what the option takes."""
    if contacts is None or isinstance(contacts, str):
        return contacts
    if isinstance(contacts, list | tuple) and all(isinstance(pair, str) for pair in contacts):
        return ",".join(contacts)
    raise UsageError(f"contacts={contacts!r}: give \"auto\", \"none\", or contact pairs as a string "
                     "\"panda/panda_leftfinger:cube,cube:table-workspace\" or a list of \"A:B\" strings")


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


def contact_channels(unwrapped: Any, spec: str | list[str] | tuple[str, ...] | None) -> list[ContactChannel]:
    """The channels for a `--contacts` spec: "auto" (default), "none", or "A:B,..." pairs (`contacts_spec`).

    Net channels cover every non-static registry actor and every articulation link; pair channels are
    the named (or automatic) pairs. Unknown body names raise ContactSpecError listing the known ones.
    """
    spec = contacts_spec(spec)
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

    Call `bind()` after each reset: a reconfiguring reset replaces the scene's bodies. A recorder may instead
    `capture()` a step's contacts as Python numbers and turn a block of captures into rows later (`row_source`, a
    `StepBuffer` row source): the same numbers, without numpy calls right after the physics step.
    """

    def __init__(self, channels: list[ContactChannel]) -> None:
        self.channels = channels
        self.row_source = ContactRows(len(channels))
        """What turns a block of `capture`s into forces (`simreel.sim.step_rows`)."""
        self._u: Any = None
        self.px: Any = None
        """The PhysX system bound (`bind`)."""

    def bind(self, unwrapped: Any) -> None:
        self._u = unwrapped
        self._n = int(unwrapped.num_envs)
        self.px = unwrapped.scene.px
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

    @property
    def captures(self) -> bool:
        """Whether `capture` works here (the CPU sim with channels); else call `sample`."""
        return bool(self.channels) and not self._gpu

    def sample(self) -> np.ndarray:
        if not self.channels:
            return np.zeros((self._n, 0, 3), np.float32)
        if self._gpu:
            return self._sample_gpu(self._n)
        return self.row_source([self.capture()])["contact_forces"][0]

    def capture(self) -> Capture | None:
        """This step's touching contacts, as (where each adds its impulse, its points' impulses) copied out in Python
        floats, with the timestep; None where nothing touches a channel (CPU sim only: `captures`)."""
        contacts = self.px.get_contacts()
        if not contacts:  # many steps of many tasks touch nothing
            return None
        hits_of, touched = self._hits, []
        for contact in contacts:
            b0, b1 = contact.bodies
            hits = hits_of.get((b0, b1))
            if hits is None:
                hits = hits_of[(b0, b1)] = self._channels_of(b0, b1)
            if hits:  # else a contact no channel records (between two static bodies, ...)
                points = contact.points
                if points:
                    touched.append((hits, [point.impulse.tolist() for point in points]))
        return (touched, self.px.timestep) if touched else None

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

    def _channels_of(self, b0: Any, b1: Any) -> list[tuple[int, float]]:
        """Where a contact between bodies b0 and b1 adds its impulse: (3 × channel, sign), in ManiSkill's signs."""
        net, pairs = self._net_index, self._pair_index
        hits = [(c, 1.0) for c in net.get(b0, ())] + [(c, -1.0) for c in net.get(b1, ())]
        for pair, sign in (((b0, b1), 1.0), ((b1, b0), -1.0)):
            c = pairs.get(pair)
            if c is not None:
                hits.append((c, sign))
        return [(3 * c, sign) for c, sign in hits]
