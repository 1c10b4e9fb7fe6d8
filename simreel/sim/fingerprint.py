"""The scene fingerprint: every physical property of a sub-scene that the state dict does not hold.

A state dict says where things are and how fast they move; it says nothing about what they are. Two scenes
with the same state layout can still differ in a cube's mass, a table's friction, a mesh, a joint's drive
gains or a controller's configuration (an asset update, domain randomization, another ManiSkill or SAPIEN
build), and then a replay diverges for reasons no state comparison can name. The fingerprint holds them:

    {"bodies": {"cube": {"type": "dynamic", "mass": 0.064, "inertia": [...], "cmass_local_pose": [...],
                         "linear_damping": 0.0, "angular_damping": 0.0,
                         "shapes": [{"shape": "box", "half_size": [...], "local_pose": [...],
                                     "static_friction": 0.3, "dynamic_friction": 0.3, "restitution": 0.0,
                                     "contact_offset": ..., "rest_offset": ...}]},
                "panda/panda_link1": {"type": "link", ..., "joint": {"type": "revolute", "limits": [[lo, hi]],
                                      "stiffness": 1000.0, "damping": 100.0, "force_limit": 100.0,
                                      "friction": 0.0, "armature": [0.0], "drive_mode": "force"}}},
     "controllers": {"panda": {"arm": {"class": "PDEEPosController", "stiffness": 1000.0, ...}}},
     "code": {"PickCubeEnv": "5f0c2a9e1b7d3c44", "BaseEnv": "a81e...", ...}}

Bodies are named as everywhere in simreel (`simreel.sim.describe.scene_bodies`); a link's entry holds the
joint that moves it. Floats are float32 values (what PhysX holds), so the same build gives equal numbers and
any difference is real; meshes are a hash of their vertices and triangles. The sim config is the recording's
`RecordingMeta.sim_config`, compared separately. ``code`` holds, per class the task is made of (its own class and
every base class up to ManiSkill's `BaseEnv`), a hash of the source file that defines it: a task whose code
changed since the recording (a reward, a constant, a reset) is named as such, where no state comparison could
say why its replay diverged. A recording made before simreel kept it has no ``code``: nothing is compared.

A recording keeps the fingerprint of the scene its recorder found (`RecordingMeta.scene_fingerprint`) and,
per episode, the entries of that episode's scene that differ from it (`EpisodeMeta.scene_changes`:
`fingerprint_changes` / `apply_changes`), so a heterogeneous task that rebuilds its scene at every reset
costs a few hundred bytes per episode, not a whole fingerprint. `scene_differences` names every
difference between two fingerprints: ``cube: mass 0.064 → 0.08``.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simreel.model.meta import json_default
from simreel.sim.describe import scene_bodies

__all__ = [
    "FINGERPRINT_SECTIONS",
    "scene_fingerprint",
    "fingerprint_changes",
    "apply_changes",
    "SceneDifference",
    "scene_differences",
]

FINGERPRINT_SECTIONS = ("bodies", "controllers", "code")
"""Top-level sections of a fingerprint, each a mapping of named entries."""

_CONTROLLER_SKIPPED = ("urdf_path", "path")
"""Controller config fields that name files on the recording machine, not physics."""


def _f32(x: Any) -> float:
    """A float32 as the shortest decimal that reads back as the same float32 (0.3, not 0.30000001192092896): equal
    float32 values give equal numbers, and the JSON stays short."""
    return float(str(np.float32(x)))


def _floats(values: Any) -> list[Any]:
    """An array of float32 values as nested lists of `_f32` numbers, shape kept."""
    a = np.asarray(values, np.float32)
    flat = [float(str(v)) for v in a.ravel()]
    return np.array(flat, dtype=object).reshape(a.shape).tolist()


def _pose(pose: Any) -> list[float]:
    return _floats([*pose.p, *pose.q])


def _mesh_hash(shape: Any) -> str:
    digest = hashlib.sha1(np.ascontiguousarray(shape.vertices, np.float32).tobytes())
    triangles = getattr(shape, "triangles", None)
    if triangles is not None:
        digest.update(np.ascontiguousarray(triangles, np.int64).tobytes())
    return digest.hexdigest()[:16]


_SHAPE_SIZES = {
    "PhysxCollisionShapeBox": ("box", ("half_size",)),
    "PhysxCollisionShapeSphere": ("sphere", ("radius",)),
    "PhysxCollisionShapeCapsule": ("capsule", ("radius", "half_length")),
    "PhysxCollisionShapeCylinder": ("cylinder", ("radius", "half_length")),
    "PhysxCollisionShapePlane": ("plane", ()),
    "PhysxCollisionShapeConvexMesh": ("convex_mesh", ("scale",)),
    "PhysxCollisionShapeTriangleMesh": ("triangle_mesh", ("scale",)),
}


def _shape(shape: Any) -> dict[str, Any]:
    kind, sizes = _SHAPE_SIZES.get(type(shape).__name__, (type(shape).__name__, ()))
    out: dict[str, Any] = {"shape": kind}
    for name in sizes:
        value = getattr(shape, name)
        out[name] = _floats(value) if np.ndim(value) else _f32(value)
    if kind.endswith("mesh"):
        out["mesh"] = _mesh_hash(shape)
    out["local_pose"] = _pose(shape.local_pose)
    out.update(_scalars(shape.physical_material, ("static_friction", "dynamic_friction", "restitution")))
    out.update(_scalars(shape, ("contact_offset", "rest_offset")))
    return out


def _scalars(obj: Any, names: tuple[str, ...]) -> dict[str, float]:
    return {name: _f32(getattr(obj, name)) for name in names}


def _joint(joint: Any) -> dict[str, Any]:
    if joint.dof == 0:  # a fixed joint has no limits or drive
        return {"type": str(joint.type)}
    out: dict[str, Any] = {"type": str(joint.type), "limits": _floats(joint.limits)}
    out.update(_scalars(joint, ("stiffness", "damping", "force_limit", "friction")))
    out.update(armature=_floats(joint.armature), drive_mode=str(joint.drive_mode))
    return out


def _body(entity: Any, body_type: str) -> dict[str, Any]:
    import sapien.physx as physx

    out: dict[str, Any] = {"type": body_type}
    for comp in entity.components:
        if not isinstance(comp, physx.PhysxRigidBaseComponent):
            continue
        if isinstance(comp, physx.PhysxRigidBodyComponent):
            out.update(mass=_f32(comp.mass), inertia=_floats(comp.inertia), cmass_local_pose=_pose(comp.cmass_local_pose))
            out.update(_scalars(comp, ("linear_damping", "angular_damping")))
        out["shapes"] = [_shape(s) for s in comp.collision_shapes]
        if isinstance(comp, physx.PhysxArticulationLinkComponent) and comp.joint is not None and not comp.is_root:
            out["joint"] = _joint(comp.joint)
    return out


def _controllers(unwrapped: Any) -> dict[str, Any]:
    agent = getattr(unwrapped, "agent", None)
    if agent is None:
        return {}
    agents = getattr(agent, "agents_dict", None) or {getattr(agent, "uid", "agent"): agent}
    out: dict[str, Any] = {}
    for uid, a in agents.items():
        controller = getattr(a, "controller", None)
        parts = getattr(controller, "controllers", None) or {"controller": controller}
        out[str(uid)] = {name: _controller(c) for name, c in parts.items() if c is not None}
    return out


def _controller(controller: Any) -> dict[str, Any]:
    config = getattr(controller, "config", None)
    fields = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else {}
    fields = {k: v for k, v in fields.items() if k not in _CONTROLLER_SKIPPED}
    out = {"class": type(controller).__name__, **fields}
    return json.loads(json.dumps(out, default=json_default))


def scene_fingerprint(unwrapped: Any, *, env_idx: int = 0) -> dict[str, Any]:
    """The fingerprint of sub-scene `env_idx` of a live ManiSkill env (see the module docstring); ~3 ms for a
    Panda scene on the CPU, so it is taken when a scene is built, never per step."""
    bodies = {b.name: _body(b.entity, b.body_type) for b in scene_bodies(unwrapped, env_idx=env_idx)}
    return {"bodies": bodies, "controllers": _controllers(unwrapped), "code": dict(_task_code(type(unwrapped)))}


def with_controllers(fingerprint: Mapping[str, Any], unwrapped: Any) -> dict[str, Any]:
    """`fingerprint` (a recording's) with the controllers of the live env `unwrapped`: what a conversion to another
    control mode changes of the scene, and all it changes (its bodies and task code are the recording's)."""
    return {**fingerprint, "controllers": _controllers(unwrapped)} if fingerprint else {}


@functools.cache
def _task_code(task: type) -> tuple[tuple[str, str], ...]:
    """(class name, hash of the source file that defines it) of `task` and each of its bases that has a Python
    source file, up to the interpreter's and gymnasium's own; read once per class in a process."""
    digests: dict[str, str] = {}
    for cls in task.__mro__:
        if cls.__module__.split(".")[0] in _CODE_SKIPPED or cls.__name__ in digests:
            continue
        try:
            path = inspect.getsourcefile(cls)
            digests[cls.__name__] = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16] if path else ""
        except (TypeError, OSError):  # a class without a source file (built in, or made at run time)
            continue
    return tuple((name, digest) for name, digest in digests.items() if digest)


_CODE_SKIPPED = ("builtins", "abc", "typing", "gymnasium")
"""Modules whose classes a task derives from that are not task code."""


# ------------------------------------------------------------------------------------------- per episode
def fingerprint_changes(base: Mapping[str, Any], fingerprint: Mapping[str, Any]) -> dict[str, Any]:
    """The entries of `fingerprint` that differ from `base`, per section; an entry only `base` has maps to None.
    Empty when the two are the same scene."""
    out: dict[str, Any] = {}
    for section in FINGERPRINT_SECTIONS:
        old, new = base.get(section, {}), fingerprint.get(section, {})
        changed = {name: entry for name, entry in new.items() if old.get(name) != entry}
        changed.update({name: None for name in old if name not in new})
        if changed:
            out[section] = changed
    return out


def apply_changes(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `changes` (from `fingerprint_changes`) applied: the fingerprint they were taken from."""
    out = {section: dict(base.get(section, {})) for section in FINGERPRINT_SECTIONS}
    for section, entries in changes.items():
        for name, entry in entries.items():
            if entry is None:
                out.setdefault(section, {}).pop(name, None)
            else:
                out.setdefault(section, {})[name] = entry
    return out


# ------------------------------------------------------------------------------------------- differences
@dataclass(frozen=True)
class SceneDifference:
    """One property that differs between the recorded scene and the replaying one.

    `subject`: a body (``cube``, ``panda/panda_link1``) or a controller (``controller panda/arm``); `prop`: the
    property path within it (``mass``, ``shapes[0].static_friction``, ``joint.stiffness``), empty when the whole
    subject exists on one side only (its value there is then ``"present"``, the other ``None``).
    """

    subject: str
    prop: str
    recorded: Any
    replaying: Any

    def describe(self) -> str:
        if not self.prop:
            side = "the recording" if self.recorded is not None else "the replaying scene"
            return f"{self.subject}: only in {side}"
        old, new = _format_pair(self.recorded, self.replaying)
        return f"{self.subject}: {self.prop} {old} → {new}"

    def to_json(self) -> dict[str, Any]:
        return {"subject": self.subject, "property": self.prop, "recorded": _json_value(self.recorded),
                "replaying": _json_value(self.replaying), "text": self.describe()}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> SceneDifference:
        return cls(str(d["subject"]), str(d.get("property", "")), d.get("recorded"), d.get("replaying"))


def _json_value(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def _format_pair(a: Any, b: Any) -> tuple[str, str]:
    """Two values with just enough digits to tell them apart (``0.064`` and ``0.08``, ``1`` and ``1.0000001``)."""
    for digits in (3, 5, 7, 9, 17):
        fa, fb = _fmt(a, digits), _fmt(b, digits)
        if fa != fb:
            return fa, fb
    return _fmt(a, 17), _fmt(b, 17)


def _fmt(x: Any, digits: int) -> str:
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return repr(x) if isinstance(x, str) else str(x)
    if isinstance(x, (int, float)):
        if math.isfinite(x) and float(x).is_integer() and abs(x) < 1e15:
            return str(int(x))
        return f"{x:.{digits}g}"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_fmt(v, digits) for v in x) + "]"
    if isinstance(x, Mapping):
        return "{" + ", ".join(f"{k}: {_fmt(v, digits)}" for k, v in x.items()) + "}"
    return repr(x)


def _leaf_differences(subject: str, prop: str, old: Any, new: Any, out: list[SceneDifference]) -> None:
    if old == new:
        return
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        for key in list(old) + [k for k in new if k not in old]:
            _leaf_differences(subject, f"{prop}.{key}" if prop else str(key), old.get(key), new.get(key), out)
        return
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new) and old and isinstance(old[0], Mapping):
        for i, (a, b) in enumerate(zip(old, new, strict=True)):
            _leaf_differences(subject, f"{prop}[{i}]", a, b, out)
        return
    if isinstance(old, list) and isinstance(new, list) and len(old) != len(new) and prop.endswith("shapes"):
        out.append(SceneDifference(subject, f"{prop} count", len(old), len(new)))
        return
    out.append(SceneDifference(subject, prop, old, new))


def scene_differences(recorded: Mapping[str, Any], replaying: Mapping[str, Any]) -> list[SceneDifference]:
    """Every property that differs between two fingerprints, bodies first, in the recorded scene's order."""
    out: list[SceneDifference] = []
    for section in FINGERPRINT_SECTIONS:
        old, new = recorded.get(section, {}), replaying.get(section, {})
        if section == "code":
            out += _code_differences(old, new)
            continue
        for name in list(old) + [n for n in new if n not in old]:
            subject = name if section == "bodies" else f"controller {name}"
            if name not in new or name not in old:
                present = "present"
                out.append(SceneDifference(subject, "", present if name in old else None,
                                           present if name in new else None))
                continue
            if section == "controllers":
                for part in list(old[name]) + [p for p in new[name] if p not in old[name]]:
                    _leaf_differences(f"controller {name}/{part}", "", old[name].get(part), new[name].get(part), out)
            else:
                _leaf_differences(subject, "", old[name], new[name], out)
    return out


def _code_differences(recorded: Mapping[str, str], replaying: Mapping[str, str]) -> list[SceneDifference]:
    """The task classes whose source file differs from the recorded one's (none where the recording has no hashes:
    made before simreel kept them)."""
    if not recorded:
        return []
    out = []
    for name in list(recorded) + [n for n in replaying if n not in recorded]:
        old, new = recorded.get(name), replaying.get(name)
        if old != new:
            subject = f"task code {name}"
            out.append(SceneDifference(subject, "", old and "present", new and "present") if old is None or new is None
                       else SceneDifference(subject, "source file hash", old, new))
    return out
