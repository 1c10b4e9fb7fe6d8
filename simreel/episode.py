"""The one episode data model shared by every format (HDF5, MCAP) and every room.

A recording is a `RecordingMeta` (everything needed to rebuild the env and judge a replay) plus a
sequence of episodes. An `Episode` holds per-step arrays; T is the number of steps:

- `actions` (T, A), `rewards` (T,), `terminated`/`truncated`/`success`/`fail` (T,) bool
- `env_states`: key path → (T+1, ...) — row 0 is the state after reset, row t+1 the state after step t
- `obs`: key path → (T+1, ...) when observations were recorded, else empty
- `info`: key → (T, ...) scalar info entries after each step (success, is_grasped, ...)
- `contact_forces`: (T, C, 3) float32 newtons, channel c described by `RecordingMeta.contact_channels[c]`
- `body_poses`: (T+1, B, 7) float32 `[x y z qw qx qy qz]` of body `RecordingMeta.pose_bodies[b]`, when
  recorded (optional: articulation link poses are not in the state dict; see `simreel.body_poses`)

Key paths are relative (`actors/cube`, not `env_states/actors/cube`); see `simreel.state_tree`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import EpisodeShapeError
from simreel.state_tree import LeafSpec, unflatten

__all__ = [
    "ContactChannel",
    "RecordingMeta",
    "EpisodeMeta",
    "Episode",
    "STEP_FIELDS",
    "FLAG_FIELDS",
    "json_default",
]

FLAG_FIELDS = ("terminated", "truncated", "success", "fail")
"""Boolean per-step fields, in the order every format stores them."""
STEP_FIELDS = ("actions", "rewards", *FLAG_FIELDS)
"""Fixed per-step fields with T rows (beside the dict-valued `info`, `contact_forces`)."""


def json_default(o: Any) -> Any:
    """`json.dumps(default=...)` for numpy scalars/arrays and tensors found in kwargs and options."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if hasattr(o, "tolist"):
        return o.tolist()
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    return repr(o)


@dataclass(frozen=True)
class ContactChannel:
    """One recorded contact-force channel.

    `kind` is "net" (the net contact force on `bodies[0]`) or "pair" (the force on `bodies[0]` from
    `bodies[1]`). Body names are `<actor>` or `<articulation>/<link>`, as in the state-dict registry.
    """

    kind: str
    bodies: tuple[str, ...]

    @property
    def name(self) -> str:
        return ":".join(self.bodies) if self.kind == "pair" else self.bodies[0]

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "bodies": list(self.bodies)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ContactChannel:
        return cls(str(d["kind"]), tuple(d["bodies"]))


@dataclass
class RecordingMeta:
    """Everything needed to rebuild the recorded env and to judge a replay of it."""

    env_id: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of `gym.make` except those below (obs_mode, control_mode, ... are separate)."""
    obs_mode: str = "state"
    control_mode: str | None = None
    reward_mode: str | None = None
    sim_backend: str = "physx_cpu"
    render_backend: str = "none"
    num_envs: int = 1
    max_episode_steps: int | None = None
    control_freq: float | None = None
    sim_freq: float | None = None
    sim_config: dict[str, Any] = field(default_factory=dict)
    action_space: dict[str, Any] = field(default_factory=dict)
    """`{"shape": [...], "dtype": ..., "low": [...], "high": [...]}` of one env's action."""
    state_layout: dict[str, LeafSpec] = field(default_factory=dict)
    obs_layout: dict[str, LeafSpec] = field(default_factory=dict)
    info_layout: dict[str, LeafSpec] = field(default_factory=dict)
    scene: dict[str, Any] = field(default_factory=dict)
    """State-dict registry names, merged views and their sub-scene indices (`simreel.scene_info`)."""
    contact_channels: list[ContactChannel] = field(default_factory=list)
    pose_bodies: list[str] = field(default_factory=list)
    """Names of the bodies whose world poses `Episode.body_poses` holds (empty: none recorded)."""
    versions: dict[str, str] = field(default_factory=dict)
    imports: list[str] = field(default_factory=list)
    """`--import` specs that registered the task; replay and view import them again."""
    created_utc: str = ""
    command: str = ""
    format_version: int = FORMAT_VERSION

    @property
    def control_period(self) -> float | None:
        """Seconds of simulated time per env step."""
        return 1.0 / self.control_freq if self.control_freq else None

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for key in ("state_layout", "obs_layout", "info_layout"):
            d[key] = {p: s.to_json() for p, s in getattr(self, key).items()}
        d["contact_channels"] = [c.to_json() for c in self.contact_channels]
        return json.loads(json.dumps(d, default=json_default))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RecordingMeta:
        known = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in d.items() if k in known}
        for key in ("state_layout", "obs_layout", "info_layout"):
            kw[key] = {p: LeafSpec.from_json(s) for p, s in d.get(key, {}).items()}
        kw["contact_channels"] = [ContactChannel.from_json(c) for c in d.get("contact_channels", [])]
        return cls(**kw)


@dataclass
class EpisodeMeta:
    """What identifies one episode and how to reproduce its reset."""

    index: int
    """Episode number in the file (`traj_<index>` in HDF5)."""
    seed: int | None = None
    """ManiSkill's episode seed: `reset(seed=seed)` reproduces the initial state."""
    reset_options: dict[str, Any] = field(default_factory=dict)
    env_idx: int = 0
    """Which parallel env (sub-scene) ran it."""
    reconfigured: bool = False
    """The reset that started this episode rebuilt the scene."""
    scene_seed: int | None = None
    """Seed of the reset that last built the scene: objects of heterogeneous tasks come from it."""
    length: int = 0
    success: bool | None = None
    """Final `info["success"]` (None if the task reports none)."""
    ever_success: bool | None = None

    def to_json(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self), default=json_default))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EpisodeMeta:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass
class Episode:
    """The arrays of one episode (see the module docstring for shapes)."""

    meta: EpisodeMeta
    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray
    fail: np.ndarray
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

    def check_shapes(self) -> None:
        """Raise `EpisodeShapeError` naming the first field whose row count does not fit T or T+1."""
        T = self.length
        for name in STEP_FIELDS:
            n = getattr(self, name).shape[0]
            if n != T:
                raise EpisodeShapeError(f"episode {self.meta.index}: {name} has {n} rows, expected {T}")
        for group, rows in (("env_states", T + 1), ("obs", T + 1), ("info", T)):
            for path, a in getattr(self, group).items():
                if a.shape[0] != rows:
                    raise EpisodeShapeError(
                        f"episode {self.meta.index}: {group}/{path} has {a.shape[0]} rows, expected {rows}"
                    )
        if self.body_poses is not None and self.body_poses.shape[0] != T + 1:
            raise EpisodeShapeError(
                f"episode {self.meta.index}: body_poses has {self.body_poses.shape[0]} rows, expected {T + 1}"
            )
        if self.contact_forces is not None and self.contact_forces.shape[0] != T:
            raise EpisodeShapeError(
                f"episode {self.meta.index}: contact_forces has {self.contact_forces.shape[0]} rows, expected {T}"
            )
