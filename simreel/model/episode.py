"""The one episode data model shared by every format (HDF5, MCAP) and every room.

A recording is a `RecordingMeta` (everything needed to rebuild the env and judge a replay) plus a
sequence of episodes. An `Episode` holds per-step arrays; T is the number of steps:

- `actions` (T, A), `rewards` (T,), `terminated`/`truncated`/`success`/`fail` (T,) bool
- `env_states`: key path → (T+1, ...) — row 0 is the state after reset, row t+1 the state after step t
- `obs`: key path → (T+1, ...) when observations were recorded, else empty
- `info`: key → (T, ...) scalar info entries after each step (success, is_grasped, ...)
- `contact_forces`: (T, C, 3) float32 newtons, channel c described by `RecordingMeta.contact_channels[c]`
- `body_poses`: (T+1, B, 7) float32 `[x y z qw qx qy qz]` of body `RecordingMeta.pose_bodies[b]`, when
  recorded (optional: articulation link poses are not in the state dict; see `simreel.sim.poses`)

Key paths are relative (`actors/cube`, not `env_states/actors/cube`); see `simreel.model.state_tree`.

On disk and in flight every array is a *field* with a flat name (`actions`, `env_states/actors/cube`,
`info/is_grasped`, `contact_forces`, ...). `episode_fields(meta)` is the one table of a recording's fields
(name, dtype, row shape, T or T+1 rows) that the recorder, every writer and every reader go by, and a
`StepBlock` carries consecutive rows of those fields from the recorder to a writer.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel.errors import EpisodeLayoutError
from simreel.model.blocks import StepBlock
from simreel.model.fields import OPTIONAL_STEP_FIELDS, STEP_FIELDS, field_group
from simreel.model.meta import EpisodeMeta
from simreel.model.state_tree import unflatten


@dataclass
class Episode:
    """The arrays of one episode (see the module docstring for shapes)."""

    meta: EpisodeMeta
    actions: np.ndarray
    rewards: np.ndarray | None
    """None where the file holds no rewards (see `OPTIONAL_STEP_FIELDS`); likewise `success`, `fail`."""
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray | None
    fail: np.ndarray | None
    env_states: dict[str, np.ndarray]
    obs: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict[str, np.ndarray] = field(default_factory=dict)
    contact_forces: np.ndarray | None = None
    body_poses: np.ndarray | None = None

    @property
    def length(self) -> int:
        return int(self.actions.shape[0])

    def state_at(self, t: int) -> dict[str, Any]:
        """The nested state dict at row t (0 = after reset), each leaf with a leading batch dim of 1."""
        return unflatten({p: a[t][None] for p, a in self.env_states.items()})

    def fields(self) -> dict[str, np.ndarray]:
        """Every array under its flat field name (see `episode_fields`); fields the episode lacks are left out."""
        out = {name: getattr(self, name) for name in STEP_FIELDS if getattr(self, name) is not None}
        for group in _GROUPS:
            out.update({f"{group}/{p}": a for p, a in getattr(self, group).items()})
        for name in _OPTIONAL:
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out

    @classmethod
    def from_fields(cls, meta: EpisodeMeta, arrays: Mapping[str, np.ndarray]) -> Episode:
        """The episode whose flat fields are `arrays` (the inverse of `fields`)."""

        missing = [name for name in STEP_FIELDS if name not in arrays and name not in OPTIONAL_STEP_FIELDS]
        if missing:
            raise EpisodeLayoutError(f"episode {meta.index}: no {', '.join(missing)}")
        return cls(
            meta=meta,
            **{name: arrays.get(name) for name in STEP_FIELDS},
            **{g: field_group(arrays, g) for g in _GROUPS},
            **{name: arrays.get(name) for name in _OPTIONAL},
        )

    def reset_block(self) -> StepBlock:
        """Row 0 of the per-state fields: the episode right after its reset."""
        return StepBlock.of({k: a[:1] for k, a in self.fields().items() if self._per_state(k)})

    def steps_block(self) -> StepBlock:
        """Every step: the per-step fields, and rows 1..T of the per-state ones."""
        return StepBlock.of({k: (a[1:] if self._per_state(k) else a) for k, a in self.fields().items()})

    def first_steps(self, steps: int) -> Episode:
        """The episode's first `steps` steps (its per-state rows up to the state after them), as views."""
        rows = {k: a[: steps + 1] if self._per_state(k) else a[:steps] for k, a in self.fields().items()}
        return Episode.from_fields(dataclasses.replace(self.meta, length=steps), rows)

    @staticmethod
    def _per_state(name: str) -> bool:
        return name == "body_poses" or name.split("/", 1)[0] in ("env_states", "obs")

    def check_shapes(self) -> None:
        """Raise `EpisodeLayoutError` naming the first field that is not a numpy array (a list would be read as some
        dtype numpy picks) or whose row count does not fit T or T+1."""
        fields = self.fields()
        for name, a in fields.items():
            if not isinstance(a, np.ndarray):
                raise EpisodeLayoutError(f"episode {self.meta.index}: {name} is a {type(a).__name__}, not a numpy "
                                         "array; give each field as an array of the layout's dtype")
        T = self.length
        for name, a in fields.items():
            rows = T + 1 if self._per_state(name) else T
            if a.shape[0] != rows:
                raise EpisodeLayoutError(f"episode {self.meta.index}: {name} has {a.shape[0]} rows, expected {rows}")


_GROUPS = ("env_states", "obs", "info")
"""Dict-valued fields of `Episode`, stored as `<group>/<key path>`."""
_OPTIONAL = ("contact_forces", "body_poses")
