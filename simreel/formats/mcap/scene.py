"""What a scene looks like, for viewers that read an MCAP file without simreel: every body's geometry as one
`foxglove.SceneUpdate` (Foxglove's 3D panel draws it, each entity locked to its body's /tf frame), and a URDF of the
same bodies (`/robot_description`, a ROS 2 `std_msgs/msg/String`, which Rerun's MCAP reader turns into 3D entities
placed by /tf). Both written once per scene, not per step (`simreel.formats.mcap.channels`).

Boxes, spheres and cylinders are the viewers' own primitives; a capsule is a cylinder and two spheres; a triangle mesh
is a `TriangleListPrimitive` (indexed) for Foxglove and, in the URDF, its bounding box in the body frame (a URDF
holds meshes only as file names, which a file that stands on its own cannot give). The geometry comes from
`simreel.model.geometry` as plain data. Messages are written with the protobuf wire format by hand (`wire`).
"""

from __future__ import annotations

import base64
import math
import struct
from collections.abc import Collection
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np

from simreel.formats.mcap.wire import double_field, len_field, varint_field
from simreel.model.geometry import RGBA, BodyGeometry, MeshPart, Primitive, SceneGeometry

__all__ = [
    "SCENE_UPDATE_SCHEMA",
    "ROBOT_DESCRIPTION_SCHEMA",
    "SceneMessages",
    "scene_messages",
    "encode_ros2_string",
]

# FileDescriptorSet of foxglove.SceneUpdate (with its dependencies), from foxglove-schemas-protobuf 0.4.0, base64.
_SCENE_UPDATE_FDS = (
    "Cl0KFGZveGdsb3ZlL0NvbG9yLnByb3RvEghmb3hnbG92ZSIzCgVDb2xvchIJCgFyGAEgASgBEgkKAWcYAiABKAESCQoBYhgD"
    "IAEoARIJCgFhGAQgASgBYgZwcm90bzMKZwoZZm94Z2xvdmUvUXVhdGVybmlvbi5wcm90bxIIZm94Z2xvdmUiOAoKUXVhdGVy"
    "bmlvbhIJCgF4GAEgASgBEgkKAXkYAiABKAESCQoBehgDIAEoARIJCgF3GAQgASgBYgZwcm90bzMKVgoWZm94Z2xvdmUvVmVj"
    "dG9yMy5wcm90bxIIZm94Z2xvdmUiKgoHVmVjdG9yMxIJCgF4GAEgASgBEgkKAXkYAiABKAESCQoBehgDIAEoAWIGcHJvdG8z"
    "CrIBChNmb3hnbG92ZS9Qb3NlLnByb3RvEghmb3hnbG92ZRoZZm94Z2xvdmUvUXVhdGVybmlvbi5wcm90bxoWZm94Z2xvdmUv"
    "VmVjdG9yMy5wcm90byJWCgRQb3NlEiMKCHBvc2l0aW9uGAEgASgLMhEuZm94Z2xvdmUuVmVjdG9yMxIpCgtvcmllbnRhdGlv"
    "bhgCIAEoCzIULmZveGdsb3ZlLlF1YXRlcm5pb25iBnByb3RvMwqHAgodZm94Z2xvdmUvQXJyb3dQcmltaXRpdmUucHJvdG8S"
    "CGZveGdsb3ZlGhRmb3hnbG92ZS9Db2xvci5wcm90bxoTZm94Z2xvdmUvUG9zZS5wcm90byKoAQoOQXJyb3dQcmltaXRpdmUS"
    "HAoEcG9zZRgBIAEoCzIOLmZveGdsb3ZlLlBvc2USFAoMc2hhZnRfbGVuZ3RoGAIgASgBEhYKDnNoYWZ0X2RpYW1ldGVyGAMg"
    "ASgBEhMKC2hlYWRfbGVuZ3RoGAQgASgBEhUKDWhlYWRfZGlhbWV0ZXIYBSABKAESHgoFY29sb3IYBiABKAsyDy5mb3hnbG92"
    "ZS5Db2xvcmIGcHJvdG8zCuMBChxmb3hnbG92ZS9DdWJlUHJpbWl0aXZlLnByb3RvEghmb3hnbG92ZRoUZm94Z2xvdmUvQ29s"
    "b3IucHJvdG8aE2ZveGdsb3ZlL1Bvc2UucHJvdG8aFmZveGdsb3ZlL1ZlY3RvcjMucHJvdG8ibgoNQ3ViZVByaW1pdGl2ZRIc"
    "CgRwb3NlGAEgASgLMg4uZm94Z2xvdmUuUG9zZRIfCgRzaXplGAIgASgLMhEuZm94Z2xvdmUuVmVjdG9yMxIeCgVjb2xvchgD"
    "IAEoCzIPLmZveGdsb3ZlLkNvbG9yYgZwcm90bzMKlQIKIGZveGdsb3ZlL0N5bGluZGVyUHJpbWl0aXZlLnByb3RvEghmb3hn"
    "bG92ZRoUZm94Z2xvdmUvQ29sb3IucHJvdG8aE2ZveGdsb3ZlL1Bvc2UucHJvdG8aFmZveGdsb3ZlL1ZlY3RvcjMucHJvdG8i"
    "mwEKEUN5bGluZGVyUHJpbWl0aXZlEhwKBHBvc2UYASABKAsyDi5mb3hnbG92ZS5Qb3NlEh8KBHNpemUYAiABKAsyES5mb3hn"
    "bG92ZS5WZWN0b3IzEhQKDGJvdHRvbV9zY2FsZRgDIAEoARIRCgl0b3Bfc2NhbGUYBCABKAESHgoFY29sb3IYBSABKAsyDy5m"
    "b3hnbG92ZS5Db2xvcmIGcHJvdG8zClsKG2ZveGdsb3ZlL0tleVZhbHVlUGFpci5wcm90bxIIZm94Z2xvdmUiKgoMS2V5VmFs"
    "dWVQYWlyEgsKA2tleRgBIAEoCRINCgV2YWx1ZRgCIAEoCWIGcHJvdG8zClQKFWZveGdsb3ZlL1BvaW50My5wcm90bxIIZm94"
    "Z2xvdmUiKQoGUG9pbnQzEgkKAXgYASABKAESCQoBeRgCIAEoARIJCgF6GAMgASgBYgZwcm90bzMKpAMKHGZveGdsb3ZlL0xp"
    "bmVQcmltaXRpdmUucHJvdG8SCGZveGdsb3ZlGhRmb3hnbG92ZS9Db2xvci5wcm90bxoVZm94Z2xvdmUvUG9pbnQzLnByb3Rv"
    "GhNmb3hnbG92ZS9Qb3NlLnByb3RvIq8CCg1MaW5lUHJpbWl0aXZlEioKBHR5cGUYASABKA4yHC5mb3hnbG92ZS5MaW5lUHJp"
    "bWl0aXZlLlR5cGUSHAoEcG9zZRgCIAEoCzIOLmZveGdsb3ZlLlBvc2USEQoJdGhpY2tuZXNzGAMgASgBEhcKD3NjYWxlX2lu"
    "dmFyaWFudBgEIAEoCBIgCgZwb2ludHMYBSADKAsyEC5mb3hnbG92ZS5Qb2ludDMSHgoFY29sb3IYBiABKAsyDy5mb3hnbG92"
    "ZS5Db2xvchIfCgZjb2xvcnMYByADKAsyDy5mb3hnbG92ZS5Db2xvchIPCgdpbmRpY2VzGAggAygHIjQKBFR5cGUSDgoKTElO"
    "RV9TVFJJUBAAEg0KCUxJTkVfTE9PUBABEg0KCUxJTkVfTElTVBACYgZwcm90bzMKrgIKHWZveGdsb3ZlL01vZGVsUHJpbWl0"
    "aXZlLnByb3RvEghmb3hnbG92ZRoUZm94Z2xvdmUvQ29sb3IucHJvdG8aE2ZveGdsb3ZlL1Bvc2UucHJvdG8aFmZveGdsb3Zl"
    "L1ZlY3RvcjMucHJvdG8itwEKDk1vZGVsUHJpbWl0aXZlEhwKBHBvc2UYASABKAsyDi5mb3hnbG92ZS5Qb3NlEiAKBXNjYWxl"
    "GAIgASgLMhEuZm94Z2xvdmUuVmVjdG9yMxIeCgVjb2xvchgDIAEoCzIPLmZveGdsb3ZlLkNvbG9yEhYKDm92ZXJyaWRlX2Nv"
    "bG9yGAQgASgIEgsKA3VybBgFIAEoCRISCgptZWRpYV90eXBlGAYgASgJEgwKBGRhdGEYByABKAxiBnByb3RvMwrnAQoeZm94"
    "Z2xvdmUvU3BoZXJlUHJpbWl0aXZlLnByb3RvEghmb3hnbG92ZRoUZm94Z2xvdmUvQ29sb3IucHJvdG8aE2ZveGdsb3ZlL1Bv"
    "c2UucHJvdG8aFmZveGdsb3ZlL1ZlY3RvcjMucHJvdG8icAoPU3BoZXJlUHJpbWl0aXZlEhwKBHBvc2UYASABKAsyDi5mb3hn"
    "bG92ZS5Qb3NlEh8KBHNpemUYAiABKAsyES5mb3hnbG92ZS5WZWN0b3IzEh4KBWNvbG9yGAMgASgLMg8uZm94Z2xvdmUuQ29s"
    "b3JiBnByb3RvMwr4AQocZm94Z2xvdmUvVGV4dFByaW1pdGl2ZS5wcm90bxIIZm94Z2xvdmUaFGZveGdsb3ZlL0NvbG9yLnBy"
    "b3RvGhNmb3hnbG92ZS9Qb3NlLnByb3RvIpoBCg1UZXh0UHJpbWl0aXZlEhwKBHBvc2UYASABKAsyDi5mb3hnbG92ZS5Qb3Nl"
    "EhEKCWJpbGxib2FyZBgCIAEoCBIRCglmb250X3NpemUYAyABKAESFwoPc2NhbGVfaW52YXJpYW50GAQgASgIEh4KBWNvbG9y"
    "GAUgASgLMg8uZm94Z2xvdmUuQ29sb3ISDAoEdGV4dBgGIAEoCWIGcHJvdG8zCqYCCiRmb3hnbG92ZS9UcmlhbmdsZUxpc3RQ"
    "cmltaXRpdmUucHJvdG8SCGZveGdsb3ZlGhRmb3hnbG92ZS9Db2xvci5wcm90bxoVZm94Z2xvdmUvUG9pbnQzLnByb3RvGhNm"
    "b3hnbG92ZS9Qb3NlLnByb3RvIqkBChVUcmlhbmdsZUxpc3RQcmltaXRpdmUSHAoEcG9zZRgBIAEoCzIOLmZveGdsb3ZlLlBv"
    "c2USIAoGcG9pbnRzGAIgAygLMhAuZm94Z2xvdmUuUG9pbnQzEh4KBWNvbG9yGAMgASgLMg8uZm94Z2xvdmUuQ29sb3ISHwoG"
    "Y29sb3JzGAQgAygLMg8uZm94Z2xvdmUuQ29sb3ISDwoHaW5kaWNlcxgFIAMoB2IGcHJvdG8zCvsBCh5nb29nbGUvcHJvdG9i"
    "dWYvZHVyYXRpb24ucHJvdG8SD2dvb2dsZS5wcm90b2J1ZiI6CghEdXJhdGlvbhIYCgdzZWNvbmRzGAEgASgDUgdzZWNvbmRz"
    "EhQKBW5hbm9zGAIgASgFUgVuYW5vc0KDAQoTY29tLmdvb2dsZS5wcm90b2J1ZkINRHVyYXRpb25Qcm90b1ABWjFnb29nbGUu"
    "Z29sYW5nLm9yZy9wcm90b2J1Zi90eXBlcy9rbm93bi9kdXJhdGlvbnBi+AEBogIDR1BCqgIeR29vZ2xlLlByb3RvYnVmLldl"
    "bGxLbm93blR5cGVzYgZwcm90bzMK/wEKH2dvb2dsZS9wcm90b2J1Zi90aW1lc3RhbXAucHJvdG8SD2dvb2dsZS5wcm90b2J1"
    "ZiI7CglUaW1lc3RhbXASGAoHc2Vjb25kcxgBIAEoA1IHc2Vjb25kcxIUCgVuYW5vcxgCIAEoBVIFbmFub3NChQEKE2NvbS5n"
    "b29nbGUucHJvdG9idWZCDlRpbWVzdGFtcFByb3RvUAFaMmdvb2dsZS5nb2xhbmcub3JnL3Byb3RvYnVmL3R5cGVzL2tub3du"
    "L3RpbWVzdGFtcHBi+AEBogIDR1BCqgIeR29vZ2xlLlByb3RvYnVmLldlbGxLbm93blR5cGVzYgZwcm90bzMKsgcKGmZveGds"
    "b3ZlL1NjZW5lRW50aXR5LnByb3RvEghmb3hnbG92ZRodZm94Z2xvdmUvQXJyb3dQcmltaXRpdmUucHJvdG8aHGZveGdsb3Zl"
    "L0N1YmVQcmltaXRpdmUucHJvdG8aIGZveGdsb3ZlL0N5bGluZGVyUHJpbWl0aXZlLnByb3RvGhtmb3hnbG92ZS9LZXlWYWx1"
    "ZVBhaXIucHJvdG8aHGZveGdsb3ZlL0xpbmVQcmltaXRpdmUucHJvdG8aHWZveGdsb3ZlL01vZGVsUHJpbWl0aXZlLnByb3Rv"
    "Gh5mb3hnbG92ZS9TcGhlcmVQcmltaXRpdmUucHJvdG8aHGZveGdsb3ZlL1RleHRQcmltaXRpdmUucHJvdG8aJGZveGdsb3Zl"
    "L1RyaWFuZ2xlTGlzdFByaW1pdGl2ZS5wcm90bxoeZ29vZ2xlL3Byb3RvYnVmL2R1cmF0aW9uLnByb3RvGh9nb29nbGUvcHJv"
    "dG9idWYvdGltZXN0YW1wLnByb3RvIqMECgtTY2VuZUVudGl0eRItCgl0aW1lc3RhbXAYASABKAsyGi5nb29nbGUucHJvdG9i"
    "dWYuVGltZXN0YW1wEhAKCGZyYW1lX2lkGAIgASgJEgoKAmlkGAMgASgJEisKCGxpZmV0aW1lGAQgASgLMhkuZ29vZ2xlLnBy"
    "b3RvYnVmLkR1cmF0aW9uEhQKDGZyYW1lX2xvY2tlZBgFIAEoCBIoCghtZXRhZGF0YRgGIAMoCzIWLmZveGdsb3ZlLktleVZh"
    "bHVlUGFpchIoCgZhcnJvd3MYByADKAsyGC5mb3hnbG92ZS5BcnJvd1ByaW1pdGl2ZRImCgVjdWJlcxgIIAMoCzIXLmZveGds"
    "b3ZlLkN1YmVQcmltaXRpdmUSKgoHc3BoZXJlcxgJIAMoCzIZLmZveGdsb3ZlLlNwaGVyZVByaW1pdGl2ZRIuCgljeWxpbmRl"
    "cnMYCiADKAsyGy5mb3hnbG92ZS5DeWxpbmRlclByaW1pdGl2ZRImCgVsaW5lcxgLIAMoCzIXLmZveGdsb3ZlLkxpbmVQcmlt"
    "aXRpdmUSMgoJdHJpYW5nbGVzGAwgAygLMh8uZm94Z2xvdmUuVHJpYW5nbGVMaXN0UHJpbWl0aXZlEiYKBXRleHRzGA0gAygL"
    "MhcuZm94Z2xvdmUuVGV4dFByaW1pdGl2ZRIoCgZtb2RlbHMYDiADKAsyGC5mb3hnbG92ZS5Nb2RlbFByaW1pdGl2ZWIGcHJv"
    "dG8zCv4BCiJmb3hnbG92ZS9TY2VuZUVudGl0eURlbGV0aW9uLnByb3RvEghmb3hnbG92ZRofZ29vZ2xlL3Byb3RvYnVmL3Rp"
    "bWVzdGFtcC5wcm90byKkAQoTU2NlbmVFbnRpdHlEZWxldGlvbhItCgl0aW1lc3RhbXAYASABKAsyGi5nb29nbGUucHJvdG9i"
    "dWYuVGltZXN0YW1wEjAKBHR5cGUYAiABKA4yIi5mb3hnbG92ZS5TY2VuZUVudGl0eURlbGV0aW9uLlR5cGUSCgoCaWQYAyAB"
    "KAkiIAoEVHlwZRIPCgtNQVRDSElOR19JRBAAEgcKA0FMTBABYgZwcm90bzMK2AEKGmZveGdsb3ZlL1NjZW5lVXBkYXRlLnBy"
    "b3RvEghmb3hnbG92ZRoaZm94Z2xvdmUvU2NlbmVFbnRpdHkucHJvdG8aImZveGdsb3ZlL1NjZW5lRW50aXR5RGVsZXRpb24u"
    "cHJvdG8iaAoLU2NlbmVVcGRhdGUSMAoJZGVsZXRpb25zGAEgAygLMh0uZm94Z2xvdmUuU2NlbmVFbnRpdHlEZWxldGlvbhIn"
    "CghlbnRpdGllcxgCIAMoCzIVLmZveGdsb3ZlLlNjZW5lRW50aXR5YgZwcm90bzM="
)
SCENE_UPDATE_SCHEMA = ("foxglove.SceneUpdate", base64.b64decode("".join(_SCENE_UPDATE_FDS)))
"""(schema name, FileDescriptorSet bytes) for an MCAP schema record with encoding "protobuf"."""
ROBOT_DESCRIPTION_SCHEMA = ("std_msgs/msg/String", "ros2msg", b"string data")
"""(schema name, schema encoding, schema text) of `/robot_description`; its messages are CDR ("cdr")."""

_IDENTITY = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
_Y90 = (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)
"""wxyz: +90° about y, which turns the z axis (Foxglove's and URDF's cylinders) onto x (SAPIEN's)."""
_POINT = np.dtype([("head", "S2"), ("tx", "S1"), ("x", "<f8"), ("ty", "S1"), ("y", "<f8"), ("tz", "S1"), ("z", "<f8")])
"""One `foxglove.Point3` as an element of a repeated field 2: tag and length, then x, y, z, each with its tag."""


@dataclass(frozen=True)
class SceneMessages:
    """One sub-scene's messages: the `foxglove.SceneUpdate` bytes, the URDF text and the entity ids it holds."""

    scene_update: bytes
    urdf: str
    entity_ids: tuple[str, ...]


# ------------------------------------------------------------------------------------------ pose arithmetic
def _quat_mul(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """Hamilton product of wxyz quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _rotate(q: tuple[float, ...], v: tuple[float, ...]) -> tuple[float, float, float]:
    w, x, y, z = _quat_mul(_quat_mul(q, (0.0, *v)), (q[0], -q[1], -q[2], -q[3]))
    return (x, y, z)


def _compose(outer: tuple[float, ...], inner: tuple[float, ...]) -> tuple[float, ...]:
    """The pose `inner` (in the frame `outer` gives) in the frame outer is given in; `[x y z qw qx qy qz]`."""
    moved = _rotate(outer[3:], inner[:3])
    return (*(o + m for o, m in zip(outer[:3], moved, strict=True)), *_quat_mul(outer[3:], inner[3:]))


def _along_x(pose: tuple[float, ...]) -> tuple[float, ...]:
    """A SAPIEN capsule's or cylinder's pose (axis along local x) as a pose whose z axis is that axis."""
    return (*pose[:3], *_quat_mul(pose[3:], _Y90))


def _caps(prim: Primitive) -> list[tuple[float, ...]]:
    """The poses of a capsule's two end spheres."""
    offset = _rotate(prim.pose[3:], (prim.size[1], 0.0, 0.0))
    return [(*(c + s * o for c, o in zip(prim.pose[:3], offset, strict=True)), *prim.pose[3:]) for s in (1.0, -1.0)]


# ------------------------------------------------------------------------------------------ foxglove.SceneUpdate
def _xyz(tag: int, v: tuple[float, ...]) -> bytes:
    return len_field(tag, double_field(0x09, v[0]) + double_field(0x11, v[1]) + double_field(0x19, v[2]))


def _pose(pose: tuple[float, ...]) -> bytes:
    """Field 1 of a primitive: `foxglove.Pose` {position=1 (Vector3), orientation=2 (Quaternion xyzw)}."""
    w, x, y, z = pose[3:]
    quat = double_field(0x09, x) + double_field(0x11, y) + double_field(0x19, z) + double_field(0x21, w)
    return len_field(0x0A, _xyz(0x0A, pose[:3]) + len_field(0x12, quat))


def _color(tag: int, rgba: RGBA) -> bytes:
    return len_field(tag, b"".join(double_field(t, c / 255.0) for t, c in zip((0x09, 0x11, 0x19, 0x21), rgba, strict=True)))


def _cube(pose: tuple[float, ...], half: tuple[float, ...], rgba: RGBA) -> bytes:
    """SceneEntity field 8: `CubePrimitive` {pose=1, size=2 (full lengths), color=3}."""
    return len_field(0x42, _pose(pose) + _xyz(0x12, tuple(2 * h for h in half)) + _color(0x1A, rgba))


def _sphere(pose: tuple[float, ...], radius: float, rgba: RGBA) -> bytes:
    """SceneEntity field 9: `SpherePrimitive` {pose=1, size=2 (diameters), color=3}."""
    return len_field(0x4A, _pose(pose) + _xyz(0x12, (2 * radius,) * 3) + _color(0x1A, rgba))


def _cylinder(pose: tuple[float, ...], radius: float, half_length: float, rgba: RGBA) -> bytes:
    """SceneEntity field 10: `CylinderPrimitive` {pose=1, size=2, bottom_scale=3, top_scale=4, color=5}; both scales
    1 (protobuf's default 0 would draw a cone's tip)."""
    size = _xyz(0x12, (2 * radius, 2 * radius, 2 * half_length))
    return len_field(0x52, _pose(_along_x(pose)) + size + double_field(0x19, 1.0) + double_field(0x21, 1.0)
                     + _color(0x2A, rgba))


def _triangles(mesh: MeshPart, pose: tuple[float, ...]) -> bytes:
    """SceneEntity field 12: `TriangleListPrimitive` {pose=1, points=2 (Point3 each), color=3, indices=5 (packed
    fixed32)}."""
    vertices = np.asarray(mesh.vertices, np.float64)
    points = np.zeros(len(vertices), _POINT)
    points["head"], points["tx"], points["ty"], points["tz"] = b"\x12\x1b", b"\x09", b"\x11", b"\x19"
    points["x"], points["y"], points["z"] = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    indices = np.ascontiguousarray(mesh.triangles, "<u4").tobytes()
    return len_field(0x62, _pose(pose) + points.tobytes() + _color(0x1A, mesh.color) + len_field(0x2A, indices))


def _shapes(body: BodyGeometry, origin: tuple[float, ...]) -> bytes:
    """A body's primitives and meshes as SceneEntity fields, each placed by `origin` (the body's pose in the entity's
    frame: the identity when the entity is locked to the body's own frame)."""
    out = []
    for prim in body.primitives:
        pose = _compose(origin, prim.pose)
        if prim.kind == "box":
            out.append(_cube(pose, prim.size, prim.color))
        elif prim.kind == "sphere":
            out.append(_sphere(pose, prim.size[0], prim.color))
        elif prim.kind in ("capsule", "cylinder"):
            out.append(_cylinder(pose, prim.size[0], prim.size[1], prim.color))
            if prim.kind == "capsule":
                out += [_sphere(_compose(origin, cap), prim.size[0], prim.color) for cap in _caps(prim)]
    out += [_triangles(mesh, origin) for mesh in body.meshes]
    return b"".join(out)


def _entity(entity_id: str, frame: str, shapes: bytes) -> bytes:
    """SceneUpdate field 2: `SceneEntity` {frame_id=2, id=3, frame_locked=5 (follows its frame), shapes}; no
    timestamp and no lifetime: it stays until replaced (Foxglove's 3D panel), and the same geometry gives the same
    bytes."""
    return len_field(0x12, len_field(0x12, frame.encode()) + len_field(0x1A, entity_id.encode())
                     + varint_field(0x28, 1) + shapes)


def _deletion(entity_id: str) -> bytes:
    """SceneUpdate field 1: `SceneEntityDeletion` {type=2 (MATCHING_ID, 0: omitted), id=3}."""
    return len_field(0x0A, len_field(0x1A, entity_id.encode()))


# ------------------------------------------------------------------------------------------ the URDF
def _rpy(q: tuple[float, ...]) -> tuple[float, float, float]:
    """URDF's roll, pitch, yaw (fixed axes x, y, z) of a wxyz quaternion."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def _origin(pose: tuple[float, ...]) -> str:
    xyz = " ".join(f"{v:.9g}" for v in pose[:3])
    rpy = " ".join(f"{v:.9g}" for v in _rpy(pose[3:]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _visual(pose: tuple[float, ...], geometry: str, rgba: RGBA) -> str:
    color = " ".join(f"{c / 255.0:.4g}" for c in rgba)
    name = "rgba_" + "_".join(str(c) for c in rgba)
    return (f"<visual>{_origin(pose)}<geometry>{geometry}</geometry>"
            f'<material name="{name}"><color rgba="{color}"/></material></visual>')


def _urdf_visuals(body: BodyGeometry, origin: tuple[float, ...]) -> list[str]:
    """A body's shapes as URDF visuals, each placed by `origin` (the body's pose in its link's frame)."""
    out = []
    for prim in body.primitives:
        r, pose = prim.size[0], _compose(origin, prim.pose)
        if prim.kind == "box":
            out.append(_visual(pose, '<box size="{:.9g} {:.9g} {:.9g}"/>'.format(*(2 * h for h in prim.size)),
                               prim.color))
        elif prim.kind == "sphere":
            out.append(_visual(pose, f'<sphere radius="{r:.9g}"/>', prim.color))
        elif prim.kind in ("capsule", "cylinder"):
            cylinder = f'<cylinder radius="{r:.9g}" length="{2 * prim.size[1]:.9g}"/>'
            out.append(_visual(_along_x(pose), cylinder, prim.color))
            if prim.kind == "capsule":
                out += [_visual(_compose(origin, cap), f'<sphere radius="{r:.9g}"/>', prim.color) for cap in _caps(prim)]
    for mesh in body.meshes:
        vertices = np.asarray(mesh.vertices, np.float64)
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        size = '<box size="{:.9g} {:.9g} {:.9g}"/>'.format(*np.maximum(high - low, 1e-4))
        out.append(_visual(_compose(origin, (*((low + high) / 2).tolist(), *_IDENTITY[3:])), size, mesh.color))
    return out


def _urdf(robot: str, world: str, fixed: list[str], links: list[tuple[str, list[str]]]) -> str:
    """A URDF whose root link `world` holds the `fixed` visuals (static bodies, at their poses), and one link per body
    of `links` (frame, visuals), each joined to the root by a floating joint: its pose comes from /tf (Rerun's MCAP
    reader takes no transform from a URDF)."""
    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(robot)}>", f"<link name={quoteattr(world)}>{''.join(fixed)}</link>"]
    for k, (frame, visuals) in enumerate(links):
        lines.append(f"<link name={quoteattr(frame)}>{''.join(visuals)}</link>")
        lines.append(f'<joint name="joint_{k}" type="floating"><parent link={quoteattr(world)}/>'
                     f"<child link={quoteattr(frame)}/></joint>")
    lines.append("</robot>")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ both
def scene_messages(geometry: SceneGeometry, frames: Collection[str], *, prefix: str = "", world: str = "world",
                   replaced: Collection[str] = ()) -> SceneMessages:
    """The messages that draw `geometry`'s bodies. A body named in `frames` (the /tf child frames, without
    `prefix`) is drawn in its frame `prefix + name`; a static one that is not, in `world` at its pose; any other
    (a link whose pose the recording does not hold) is left out, as is a body without shapes. Entities are named
    like their frames; those of `replaced` (written before for this sub-scene) that this scene lacks are deleted."""
    frame_set = set(frames)
    entities: list[bytes] = []
    ids: list[str] = []
    fixed: list[str] = []
    links: list[tuple[str, list[str]]] = []
    for body in geometry.bodies:
        if body.empty or (body.name not in frame_set and body.world_pose is None):
            continue
        entity_id = prefix + body.name
        if body.name in frame_set:
            entities.append(_entity(entity_id, entity_id, _shapes(body, _IDENTITY)))
            links.append((entity_id, _urdf_visuals(body, _IDENTITY)))
        else:
            at = tuple(body.world_pose or _IDENTITY)
            entities.append(_entity(entity_id, world, _shapes(body, at)))
            fixed += _urdf_visuals(body, at)
        ids.append(entity_id)
    kept = set(ids)
    deletions = [_deletion(i) for i in replaced if i not in kept]
    robot = prefix.rstrip("/") or "scene"
    return SceneMessages(b"".join(deletions + entities), _urdf(robot, world, fixed, links), tuple(ids))


def encode_ros2_string(text: str) -> bytes:
    """A ROS 2 `std_msgs/msg/String` in CDR: the little-endian encapsulation header, the length of the UTF-8 text
    with its NUL, the text, the NUL."""
    data = text.encode() + b"\0"
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(data)) + data
