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

Key paths are relative (`actors/cube`, not `env_states/actors/cube`); see `simreel.state_tree`.

On disk and in flight every array is a *field* with a flat name (`actions`, `env_states/actors/cube`,
`info/is_grasped`, `contact_forces`, ...). `episode_fields(meta)` is the one table of a recording's fields
(name, dtype, row shape, T or T+1 rows) that the recorder, every writer and every reader go by, and a
`StepBlock` carries consecutive rows of those fields from the recorder to a writer.
"""

from __future__ import annotations

import base64
import binascii
import bisect
import dataclasses
import functools
import itertools
import json
import types
import typing
import uuid
import zlib
from collections.abc import Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import EpisodeLayoutError, MetadataError, UsageError
from simreel.option_checks import is_whole_number
from simreel.state_tree import LeafSpec, unflatten

__all__ = [
    "new_recording_id",
    "field_group",
    "ContactChannel",
    "RecordingMeta",
    "EpisodeMeta",
    "EpisodeSelection",
    "Episode",
    "FieldSpec",
    "StepBlock",
    "episode_fields",
    "join_blocks",
    "STEP_FIELDS",
    "FLAG_FIELDS",
    "OPTIONAL_STEP_FIELDS",
    "json_default",
]

FLAG_FIELDS = ("terminated", "truncated", "success", "fail")
"""Boolean per-step fields, in the order every format stores them."""
STEP_FIELDS = ("actions", "rewards", *FLAG_FIELDS)
"""Fixed per-step fields with T rows (beside the dict-valued `info`, `contact_forces`)."""
OPTIONAL_STEP_FIELDS = ("rewards", "success", "fail")
"""Fixed per-step fields a file may not hold (ManiSkill's files without rewards, success or fail): listed in
`RecordingMeta.unknown`, left out of the field table, None in the `Episode`, never invented."""


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


def _accepts(annotation: Any) -> tuple[type, ...]:
    """The JSON value types a field annotated `annotation` accepts (an int where a float is declared)."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        return tuple(t for arg in typing.get_args(annotation) for t in _accepts(arg))
    origin = typing.get_origin(annotation) or annotation
    if annotation is type(None):
        return (type(None),)
    if origin is float:
        return (int, float)
    return (origin,) if isinstance(origin, type) else (object,)


def _type_name(annotation: Any) -> str:
    return annotation.__name__ if isinstance(annotation, type) else str(annotation).replace("typing.", "")


def _fields_from_json(cls: type, d: Any, what: str) -> dict[str, Any]:
    """The fields of dataclass `cls` found in JSON object `d`, each checked against its declared type;
    `MetadataError` naming `what`, the field and what was found. Unknown keys are ignored (newer writers)."""
    if not isinstance(d, Mapping):
        raise MetadataError(f"{what} is {type(d).__name__}, expected a JSON object")
    out = {}
    for name, required, accepted, hint in _json_fields(cls):
        if name not in d:
            if required:
                raise MetadataError(f"{what} lacks {name!r}")
            continue
        value = d[name]
        if not isinstance(value, accepted) or (isinstance(value, bool) and bool not in accepted):
            raise MetadataError(f"{what}: {name} is {value!r}, expected {_type_name(hint)}")
        out[name] = value
    return out


@functools.cache
def _json_fields(cls: type) -> tuple[tuple[str, bool, tuple[type, ...], Any], ...]:
    """(name, required, the JSON value types it accepts, its annotation) of each field of dataclass `cls`, worked out
    once per class: `typing.get_type_hints` evaluates every annotation, ~0.2 ms a call, and a reader parses the
    metadata of every episode (a writer each episode's twice, `EpisodeWriter.checked_meta`)."""
    hints = typing.get_type_hints(cls)
    return tuple((f.name, f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING,
                  _accepts(hints[f.name]), hints[f.name]) for f in dataclasses.fields(cls))


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
        """`MetadataError` unless `d` is a net channel of one body or a pair channel of two."""
        if not isinstance(d, Mapping):
            raise MetadataError(f"contact channel {d!r}: expected {{'kind': 'net' | 'pair', 'bodies': [...]}}")
        kind, bodies = d.get("kind"), d.get("bodies")
        count = {"net": 1, "pair": 2}.get(kind) if isinstance(kind, str) else None
        if count is None or not isinstance(bodies, list) or len(bodies) != count or not all(
            isinstance(b, str) and b for b in bodies
        ):
            raise MetadataError(f"contact channel {dict(d)!r}: expected kind 'net' with 1 body name or 'pair' with 2")
        return cls(kind, tuple(bodies))


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
    """State-dict registry names, merged views and their sub-scene indices (`simreel.sim.describe`)."""
    contact_channels: list[ContactChannel] = field(default_factory=list)
    pose_bodies: list[str] = field(default_factory=list)
    """Names of the bodies whose world poses `Episode.body_poses` holds (empty: none recorded)."""
    versions: dict[str, str] = field(default_factory=dict)
    scene_fingerprint: dict[str, Any] = field(default_factory=dict)
    """Physical properties of the scene the recorder found (masses, shapes, materials, joints, controllers: see
    `simreel.sim.fingerprint`); replay names every difference before it compares a step. Empty in files
    recorded before simreel kept it: then nothing is compared. Stored packed (`_pack_json`): ~12 KB of JSON for
    PickCube-v1, 1/5 of that packed, which a short recording's size would otherwise feel."""
    imports: list[str] = field(default_factory=list)
    """`--import` specs that registered the task (a file by its absolute path, a module by its name); replay and
    view import them again, found as `simreel.sim.user_code.resolve_task_imports` says."""
    created_utc: str = ""
    command: str = ""
    recording_id: str = ""
    """A random id (`new_recording_id`) of the run that stepped the episodes this file records (those whose
    `EpisodeMeta.origin` or `provenance` names no scene of another recording): what the scene history of copies of
    them names their recording by (`simreel.scene_history`), so that a moved file is still the same recording and a
    new recording at the same path is not. Copies of a whole file (`recover`, a format copy, a byte copy) keep it;
    every other file simreel writes gets a new one. Empty in files written before simreel kept it, and ManiSkill's:
    they are known by their path."""
    format_version: int = FORMAT_VERSION
    source: dict[str, Any] = field(default_factory=dict)
    """Where the recording came from when simreel did not record it: ``{"format": "maniskill", "source_type",
    "source_desc", "commit_info", ...}`` as the file says (empty for simreel recordings)."""
    unknown: list[str] = field(default_factory=list)
    """What the file does not hold, never invented: step fields (``rewards``, ``success``, ``fail``; left out
    of the field table) and facts a replay cannot check (``versions``, ``sim_config``, ``control_freq``,
    ``contacts``, ``scene_seeds``, ``body_poses``, ``info``, ``env_states``). Empty for simreel recordings."""
    provenance: dict[str, Any] = field(default_factory=dict)
    """What made this file from other recordings (empty for a recording made by recording), by ``"operation"``:
    ``"merge"`` / ``"filter"``: ``{"operation", "inputs": [{"path", "size", "mtime_ns", "meta_digest", "kind",
    "episodes", "versions", "created_utc", "command", "source", "provenance"}, ...], "criteria": {...}, "part": "kept"
    | "rest"}`` (`simreel.formats.dataset`; size and mtime as `simreel.formats.inputs.file_identity` says); ``"convert"`` (``simreel convert`` to a new observation or control
    mode): ``{"operation", "source": path, "source_kind", "source_episodes", "conversion": {what changed, how it
    was checked}, "tolerances", "filters", "source_recording_id"}``, each episode's own verdict in
    `EpisodeMeta.provenance`; ``"replay"`` (``simreel replay -o``): ``{"operation", "source": path,
    "source_recording_id", "mode", "resync", "tolerances", "input": the source's own provenance, if any}``, each
    episode's verdict in `EpisodeMeta.verification`. Unlike `source`, which says where a file simreel did not record
    came from."""

    @property
    def control_period(self) -> float | None:
        """Seconds of simulated time per env step."""
        return 1.0 / self.control_freq if self.control_freq else None

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for key in ("state_layout", "obs_layout", "info_layout"):
            d[key] = {p: s.to_json() for p, s in getattr(self, key).items()}
        d["contact_channels"] = [c.to_json() for c in self.contact_channels]
        d["scene_fingerprint"] = _pack_json(self.scene_fingerprint)
        return json.loads(json.dumps(d, default=json_default))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RecordingMeta:
        """The metadata of JSON object `d`; `MetadataError` naming the first field that is missing or malformed."""
        kw = _fields_from_json(cls, d, "recording metadata")
        for key in ("state_layout", "obs_layout", "info_layout"):
            kw[key] = {p: LeafSpec.from_json(s) for p, s in kw.get(key, {}).items()}
        kw["contact_channels"] = [ContactChannel.from_json(c) for c in kw.get("contact_channels", [])]
        kw["scene_fingerprint"] = _unpack_json(kw.get("scene_fingerprint", {}), "recording metadata: scene_fingerprint")
        if kw.get("num_envs", 1) < 1:
            raise MetadataError(f"recording metadata: num_envs is {kw['num_envs']}, expected >= 1")
        shape = kw.get("action_space", {}).get("shape", [])
        if not isinstance(shape, list) or not all(isinstance(x, int) and x >= 0 for x in shape):
            raise MetadataError(f"recording metadata: action_space shape is {shape!r}, expected a list of sizes")
        return cls(**kw)


_PACKED = "zlib+base64"


def _pack_json(d: dict[str, Any]) -> dict[str, Any]:
    """`d` as ``{"zlib+base64": <its JSON, compressed>}``, for large metadata that file attributes and MCAP metadata
    records store uncompressed; empty stays empty."""
    if not d:
        return {}
    text = json.dumps(d, default=json_default, separators=(",", ":"))
    return {_PACKED: base64.b64encode(zlib.compress(text.encode(), 9)).decode("ascii")}


def _unpack_json(d: Any, what: str) -> dict[str, Any]:
    """The dict `_pack_json` packed (a plain dict is returned as it is); `MetadataError` naming `what` if damaged."""
    if not isinstance(d, dict):
        raise MetadataError(f"{what} is {type(d).__name__}, expected a JSON object")
    if set(d) != {_PACKED}:
        return d
    try:
        out = json.loads(zlib.decompress(base64.b64decode(d[_PACKED], validate=True)))
    except (binascii.Error, zlib.error, ValueError, TypeError) as exc:
        raise MetadataError(f"{what}: the packed JSON does not decode ({exc}); the file's metadata is damaged") from exc
    if not isinstance(out, dict):
        raise MetadataError(f"{what}: packed {type(out).__name__}, expected a JSON object")
    return out


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
    reconfigured: bool | None = False
    """The reset that started this episode rebuilt the scene (None: unknown, as in ManiSkill's files: the reset is
    then reproduced as given, and the task rebuilds its scene when it would)."""
    scene_seed: int | None = None
    """Seed of the reset that last built the scene: objects of heterogeneous tasks come from it."""
    scene_changes: dict[str, Any] = field(default_factory=dict)
    """Where this episode's scene differs from `RecordingMeta.scene_fingerprint` (a rebuilt scene, another
    sub-scene): the changed fingerprint entries (`simreel.sim.fingerprint.fingerprint_changes`); empty: the same."""
    chain: dict[str, int] = field(default_factory=dict)
    """Where its recorder's scene ran it: ``{"start": <index of the first episode that scene ran since it was built>,
    "position": <episodes it ran before this one>}`` (`simreel.scene_history`), so that an episode its file lacks
    (damaged, lost by recover) is noticed; of the recording it was recorded in (a copy's `origin` says which).
    Empty where unknown (ManiSkill's files, simreel's from before it noted it): the file's order then tells."""
    length: int = 0
    success: bool | None = None
    """Final `info["success"]` (None if the task reports none)."""
    ever_success: bool | None = None
    initial_state_known: bool = True
    """False where the file's state row 0 is not the state after the reset (ManiSkill's replay_trajectory writes
    the state after step 0 there in its state modes): replays then do not compare row 0."""
    notes: list[str] = field(default_factory=list)
    """What the recorder noted about this episode (``cut short: ...`` when a stop ended the recording before the
    episode ended) and what the reader found about it in the file (quirks, mismatches), for reports."""
    origin: dict[str, Any] = field(default_factory=dict)
    """Where a merged or filtered episode was copied from: ``{"file": <absolute path>, "index": <its index
    there>}``, where it ran when it was recorded, ``"scene": {"file": <the recording>, "recording": <its
    `RecordingMeta.recording_id`, where it has one>, "start": <index there of the first episode of its scene chain>,
    "position": <episodes of that chain before it>}`` (`simreel.scene_history`; absent where unknown), and that episode's own ``"origin"`` when it had one (empty for a recorded episode)."""
    provenance: dict[str, Any] = field(default_factory=dict)
    """For an episode of a converted recording: ``{"source_episode": index in the source, "verdict", "checked",
    "first_exceeded", "max_error"}`` as the conversion judged it (see `RecordingMeta.provenance`), and ``"scene"``,
    where it ran (as in `origin`; `simreel.replay.convert.ConvertJob.scenes`)."""
    verification: dict[str, Any] = field(default_factory=dict)
    """In a file written by ``simreel replay -o``: the replay's verdict on this episode (verdict, first divergence,
    scene differences, explanation: `simreel.replay.report.EpisodeReport.verification`); empty elsewhere."""

    def to_json(self) -> dict[str, Any]:
        """Its fields as JSON values, new objects throughout (the JSON round trip copies; `dataclasses.asdict`'s deep
        copy before it doubled the cost, and every writer does this several times an episode)."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return json.loads(json.dumps(fields, default=json_default))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EpisodeMeta:
        """The metadata of JSON object `d`; `MetadataError` naming the first field that is missing or malformed."""
        kw = _fields_from_json(cls, d, "episode metadata")
        for name in ("index", "length", "env_idx"):
            if kw.get(name, 0) < 0:
                raise MetadataError(f"episode metadata: {name} is {kw[name]}, expected >= 0")
        _check_chain(kw.get("chain") or {})
        _check_scene(kw.get("origin") or {}, "origin")
        _check_scene(kw.get("provenance") or {}, "provenance")
        return cls(**kw)


@dataclass(frozen=True)
class EpisodeSelection:
    """Episode indices named as a list of ranges, ``0,3-7`` (``--episodes``), kept as those ranges: what it costs
    depends on the text and on the episodes a file has, never on the numbers (``0-99999999999`` is two of them).

    It is iterated (the indices in the order named, a range one index at a time, repeats kept), asked whether it
    holds an index and whether it names any; `pick` and `missing` answer for a file's episodes in time and memory
    bounded by those. Nothing asks for its length or a list of all it names: that is what a huge range must not
    build.
    """

    ranges: tuple[tuple[int, int], ...]
    """(first, last) of each part, in the order named; first <= last."""

    @classmethod
    def parse(cls, text: str) -> EpisodeSelection:
        """``"0,3-7"`` → ranges (0, 0) and (3, 7); an empty part is skipped. `ValueError` for a part that is not N or
        N-M with M >= N, each a number of ASCII digits only (no sign, no ``1_0``: Python's int() takes those)."""
        ranges = []
        for part in text.split(","):
            if part.strip():
                first, _, last = part.partition("-") if "-" in part else (part, "", part)
                lo, hi = _digits(first), _digits(last)
                if hi < lo:
                    raise ValueError(f"range {part.strip()!r} runs backwards")
                ranges.append((lo, hi))
        return cls(tuple(ranges))

    @classmethod
    def of(cls, value: EpisodeSelection | str | Iterable[int] | None, *,
           name: str = "episodes") -> EpisodeSelection | None:
        """`value` as a selection: None stays None, text is parsed, indices (a library caller's list, a report's)
        are one range each, in their order. Anything else is `UsageError` saying what to give: a number alone, a
        bool, a float, a negative index (the text takes none either), text that `parse` refuses. `name`: the option
        it was given as, for the message."""
        if value is None or isinstance(value, EpisodeSelection):
            return value
        try:
            if isinstance(value, str):
                return cls.parse(value)
            if isinstance(value, (bytes, bytearray)) or not isinstance(value, Iterable):
                raise ValueError("not a list of indices")
            return cls(tuple((i, i) for i in map(_episode_index, value)))
        except ValueError as e:
            raise UsageError(f"{name}={value!r}: {e}; give episode indices, ints >= 0 (e.g. [0, 3]), their text as "
                             "--episodes takes it (\"0,3-7\"), or None (all)") from None

    def __iter__(self) -> Iterator[int]:
        for lo, hi in self.ranges:
            yield from range(lo, hi + 1)

    def __contains__(self, index: object) -> bool:
        return any(lo <= index <= hi for lo, hi in self.ranges)  # type: ignore[operator]

    def __bool__(self) -> bool:
        return bool(self.ranges)

    def __str__(self) -> str:
        """As it would be typed: ``0,3-7``."""
        return ",".join(str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in self.ranges)

    def to_json(self) -> str:
        """Its text (`__str__`), which `of` reads back: a report keeps it whatever the numbers."""
        return str(self)

    def pick(self, have: Iterable[int]) -> list[int]:
        """The indices named that are in `have` (a file's episodes), each once, in the order named: a range longer
        than `have` is walked through `have`, so the work is bounded by `have`, not by the range."""
        held = set(have)
        present = sorted(held)
        found: dict[int, None] = {}
        for lo, hi in self.ranges:
            if hi - lo < len(present):
                found.update((i, None) for i in range(lo, hi + 1) if i in held)
            else:
                found.update((i, None) for i in present[bisect.bisect_left(present, lo):bisect.bisect_right(present, hi)])
        return list(found)

    def missing(self, have: Collection[int], limit: int) -> list[int]:
        """The first `limit` indices named that `have` lacks, each once, in the order named: a range walked past
        `have` and those found already yields a lacking index at least every ``len(have) + limit + 1`` steps, so the
        work is bounded by `have` and `limit`, not by the range."""
        lacking: dict[int, None] = {}
        for lo, hi in self.ranges:
            walk = (i for i in range(lo, hi + 1) if i not in have and i not in lacking)
            lacking.update((i, None) for i in itertools.islice(walk, limit - len(lacking)))
            if len(lacking) >= limit:
                break
        return list(lacking)


def _episode_index(value: Any) -> int:
    """An episode index a library caller gave: an int (a numpy int too) >= 0, else `ValueError` (a bool too: True
    is not episode 1)."""
    if not is_whole_number(value):
        raise ValueError(f"{value!r} is not a whole number")
    if value < 0:
        raise ValueError(f"{value} is negative")
    return int(value)


def _digits(text: str) -> int:
    """The number `text` writes (spaces around it allowed) in ASCII digits only; `ValueError` for anything else."""
    text = text.strip()
    if not (text.isascii() and text.isdigit()):
        raise ValueError(f"{text!r} is not a number of digits")
    return int(text)


def new_recording_id() -> str:
    """A new `RecordingMeta.recording_id`: 32 random hex digits."""
    return uuid.uuid4().hex


def _check_chain(chain: dict[str, Any]) -> None:
    """`MetadataError` unless `chain` (`EpisodeMeta.chain`, not empty) holds a start and a position (other keys, of a
    later simreel, are kept)."""
    if chain and not all(type(chain.get(k)) is int and chain[k] >= 0 for k in ("start", "position")):
        raise MetadataError(f"episode metadata: chain is {json.dumps(chain, default=str)[:200]}, expected "
                            '{"start": <index>, "position": <count>}')


def _check_scene(holder: dict[str, Any], name: str) -> None:
    """`MetadataError` unless ``holder["scene"]`` (of `EpisodeMeta` field `name`), where given, is what
    `EpisodeMeta.origin` describes."""
    scene = holder.get("scene")
    if scene is None:
        return
    ok = isinstance(scene, dict) and isinstance(scene.get("file"), str) and all(
        type(scene.get(k)) is int and scene[k] >= 0 for k in ("start", "position")) and isinstance(
        scene.get("recording", ""), str)
    if not ok:
        raise MetadataError(f"episode metadata: {name}.scene is {json.dumps(scene, default=str)[:200]}, expected "
                            '{"file": <path>, "recording": <id>, "start": <index>, "position": <count>}')


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


@dataclass(frozen=True)
class StepBlock:
    """Consecutive rows of one episode: flat field name → array of `rows` rows (see `episode_fields`).

    The recorder fills blocks of steps (each per-state field holding the states *after* those steps) and
    the reset row (per-state fields only, one row); writers consume them. `conform` checks a block
    against the field table.

    A recorder may leave some fields as it captured them, for its writer process to convert (`captured`: each
    (row source, its captures of these rows, env), the source a `simreel.sim.step_rows` class that makes
    (rows, num_envs, ...) arrays of the fields it `names`); `converted` makes them arrays.
    """

    arrays: Mapping[str, np.ndarray]
    rows: int
    captured: tuple[tuple[Any, list[Any], int], ...] = ()

    @classmethod
    def of(cls, arrays: Mapping[str, Any]) -> StepBlock:
        """A block of `arrays` (all with the same number of rows)."""
        arrays = {name: np.asarray(a) for name, a in arrays.items()}
        counts = {a.shape[0] if a.ndim else -1 for a in arrays.values()}
        if len(counts) > 1:
            raise EpisodeLayoutError(f"a step block mixes row counts {sorted(counts)}")
        return cls(arrays, counts.pop() if counts else 0)

    def __len__(self) -> int:
        return self.rows

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def get(self, name: str) -> np.ndarray | None:
        return self.arrays.get(name)

    def converted(self) -> StepBlock:
        """This block with every field an array: its captured fields converted."""
        if not self.captured:
            return self
        arrays = dict(self.arrays)
        for source, captures, env in self.captured:
            arrays.update({name: rows[:, env] for name, rows in source(captures).items()})
        return StepBlock(arrays, self.rows)

    def conform(self, fields: Iterable[FieldSpec], *, episode: int) -> dict[str, np.ndarray]:
        """The block's arrays for exactly `fields`, each cast to its dtype (no copy when it has it already:
        `_cast_keeping_values`); a field still `captured` counts as there, unchecked until it is converted.

        Raises `EpisodeLayoutError` naming the episode and the field when one is missing, has another row
        shape, holds a value its dtype cannot hold, or when the block holds a field the table does not list (it would
        be dropped silently).
        """
        captured = {name for source, _, _ in self.captured for name in source.names}
        out: dict[str, np.ndarray] = {}
        listed = set()
        for f in fields:
            listed.add(f.name)
            a = self.arrays.get(f.name)
            if a is None:
                if f.name in captured:
                    continue
                raise EpisodeLayoutError(f"episode {episode}: no {f.name} to write (the recording's layout lists it)")
            if a.shape != (self.rows, *f.shape):
                raise EpisodeLayoutError(
                    f"episode {episode}: {f.name} has shape {a.shape}, expected {(self.rows, *f.shape)} from the layout"
                )
            out[f.name] = _cast_keeping_values(a, np.dtype(f.dtype), f"episode {episode}: {f.name}")
        extra = sorted((set(self.arrays) | captured) - listed)
        if extra:
            raise EpisodeLayoutError(
                f"episode {episode}: {', '.join(extra[:3])} not in the recording's layout; describe every field in "
                "the RecordingMeta (state_layout, obs_layout, info_layout, contact_channels, pose_bodies)"
            )
        return out


def _cast_keeping_values(a: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
    """`a` as `dtype` (no copy when it has it already) where the cast keeps every value: a type that holds all of
    `a`'s (``can_cast`` "safe"), a float type of the values rounded but none overflowed to infinity, an integer or bool
    type that holds each value exactly (0 and 1 for bool). Anything else is `EpisodeLayoutError` naming `what`: numpy's
    cast would store other values than given and say nothing (1e300 as inf, 2**40 as 0 in int32, 0.5 and NaN as True,
    a complex number's real part, text parsed as numbers)."""
    if a.dtype == dtype or np.can_cast(a.dtype, dtype, "safe"):
        return a.astype(dtype, copy=False)
    if a.dtype.kind not in "biuf":
        raise EpisodeLayoutError(f"{what} is {a.dtype}, not numbers of the layout's {dtype}; give values of that dtype")
    with np.errstate(over="ignore", invalid="ignore"):
        out = a.astype(dtype)
        changed = (np.isinf(out) & ~np.isinf(a)) if dtype.kind == "f" else ~(out.astype(a.dtype) == a)
    if changed.any():
        first = np.argwhere(changed)[0]
        raise EpisodeLayoutError(f"{what} holds {a[tuple(first)].item()!r} ({a.dtype}), which {dtype} cannot hold (it would be "
                                 f"stored as {out[tuple(first)].item()!r}); give values of that dtype")
    return out


def join_blocks(fields: Sequence[FieldSpec], reset: StepBlock, steps: Sequence[StepBlock]) -> dict[str, np.ndarray]:
    """The whole arrays of `fields` from an episode's reset row and its consecutive step blocks, in order: per-state
    fields are the reset row and then every block's rows (the states after those steps), per-step fields every
    block's rows. The inverse of `Episode.reset_block` + `Episode.steps_block`; the one place an episode read in
    blocks is put back together."""
    out: dict[str, np.ndarray] = {}
    for f in fields:
        parts = ([reset[f.name]] if f.per_state else []) + [b[f.name] for b in steps]
        out[f.name] = np.concatenate(parts) if parts else np.empty((0, *f.shape), f.dtype)
    return out


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
