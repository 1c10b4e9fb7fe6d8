"""The field table: every array of every episode of a recording, with its flat name, dtype, row shape and row
count (`episode_fields`), the one table the recorder, every writer and every reader go by."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from simreel.model.meta import RecordingMeta

FLAG_FIELDS = ("terminated", "truncated", "success", "fail")
"""Boolean per-step fields, in the order every format stores them."""
STEP_FIELDS = ("actions", "rewards", *FLAG_FIELDS)
"""Fixed per-step fields with T rows (beside the dict-valued `info`, `contact_forces`)."""
OPTIONAL_STEP_FIELDS = ("rewards", "success", "fail")
"""Fixed per-step fields a file may not hold (ManiSkill's files without rewards, success or fail): listed in
`RecordingMeta.unknown`, left out of the field table, None in the `Episode`, never invented."""


@dataclass(frozen=True)
class FieldSpec:
    """One array of every episode of a recording: its flat name, dtype, row shape and row count."""

    name: str
    """`actions`, `rewards`, a flag, `info/<key>`, `contact_forces`, `env_states/<key path>`, `obs/<key path>`
    or `body_poses`."""
    dtype: str
    """numpy dtype name (`float32`, `bool`, ...), as stored."""
    shape: tuple[int, ...]
    """Shape of one row."""
    per_state: bool = False
    """True: T+1 rows (row 0 after reset, row t+1 after step t); False: T rows, one per step."""

    @property
    def rows(self) -> str:
        """``"T+1"`` or ``"T"``, for messages and docs."""
        return "T+1" if self.per_state else "T"

    def row_count(self, steps: int) -> int:
        """How many rows this field has in an episode of `steps` steps."""
        return steps + 1 if self.per_state else steps


def episode_fields(meta: RecordingMeta) -> list[FieldSpec]:
    """The field table of every episode of a recording with metadata `meta`, in storage order: the per-step
    fields (actions, rewards, flags, info, contact forces), then the per-state ones (state, obs, poses)."""
    fields = [
        FieldSpec("actions", "float32", tuple(int(x) for x in meta.action_space.get("shape", [0]))),
        FieldSpec("rewards", "float32", ()),
        *(FieldSpec(name, "bool", ()) for name in FLAG_FIELDS),
        *(FieldSpec(f"info/{k}", s.dtype, tuple(s.shape)) for k, s in meta.info_layout.items()),
    ]
    fields = [f for f in fields if f.name not in meta.unknown]
    if meta.contact_channels:
        fields.append(FieldSpec("contact_forces", "float32", (len(meta.contact_channels), 3)))
    fields += [FieldSpec(f"env_states/{p}", s.dtype, tuple(s.shape), True) for p, s in meta.state_layout.items()]
    fields += [FieldSpec(f"obs/{p}", s.dtype, tuple(s.shape), True) for p, s in meta.obs_layout.items()]
    if meta.pose_bodies:
        fields.append(FieldSpec("body_poses", "float32", (len(meta.pose_bodies), 7), True))
    return fields


def field_group(arrays: Mapping[str, Any], group: str) -> dict[str, Any]:
    """The fields of `group` (``env_states``, ``obs``, ``info``) among flat `arrays`, by their key path inside it."""
    prefix = group + "/"
    return {k[len(prefix):]: a for k, a in arrays.items() if k.startswith(prefix)}


