"""Recording and episode metadata: `RecordingMeta` (everything needed to rebuild the env and judge a replay),
`EpisodeMeta` (one episode's seed, length, chain and origin), `ContactChannel`, and their JSON codecs."""

from __future__ import annotations

import base64
import binascii
import dataclasses
import functools
import json
import types
import typing
import uuid
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simreel import FORMAT_VERSION
from simreel.errors import MetadataError
from simreel.model.json_input import json_value
from simreel.model.lineage import EpisodeOrigin, EpisodeProvenance, EpisodeVerification, SceneChain
from simreel.model.state_tree import LeafSpec


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
    if isinstance(origin, type) and hasattr(origin, "from_json"):
        return (dict,)  # a record, as its JSON object (checked by its `from_json`)
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
    them names their recording by (`simreel.verdicts.scene_history`), so that a moved file is still the same recording and a
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
    | "rest"}`` (`simreel.datasets.dataset`; size and mtime as `simreel.datasets.inputs.file_identity` says); ``"convert"`` (``simreel convert`` to a new observation or control
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
        out = json_value(zlib.decompress(base64.b64decode(d[_PACKED], validate=True)), "the packed JSON")
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
    chain: SceneChain | None = None
    """Where its recorder's scene ran it (`SceneChain`: the index of the first episode that scene ran since it was
    built, and the episodes it ran before this one; `simreel.verdicts.scene_history`), so that an episode its file
    lacks (damaged, lost by recover) is noticed; of the recording it was recorded in (a copy's `origin` says which).
    None where unknown (ManiSkill's files, simreel's from before it noted it): the file's order then tells."""
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
    origin: EpisodeOrigin | None = None
    """Where a merged or filtered episode was copied from (`EpisodeOrigin`: the file and the index there, where it ran
    when it was recorded, and that episode's own origin when it was a copy too); None for a recorded episode."""
    provenance: EpisodeProvenance | None = None
    """For an episode of a converted recording: the episode it converts, the verdict, what was checked, the first
    error past its tolerance and the largest errors, as the conversion judged it (`EpisodeProvenance`; see
    `RecordingMeta.provenance`), and where it ran (`simreel.replay.convert.job.ConvertJob.scenes`); for an episode
    of a replay's output, the scene the replay ran it in. None for a recorded episode (``{}`` in the file)."""
    verification: EpisodeVerification | None = None
    """In a file written by ``simreel replay -o``: the replay's verdict on this episode (`EpisodeVerification`:
    verdict, first divergence, scene differences, explanation:
    `simreel.replay.report.report.EpisodeReport.verification`); None elsewhere (``{}`` in the file)."""
    reset_generators: dict[str, str] = field(default_factory=dict)
    """For an episode reset without a seed in a one-env recording: the state, just before that reset, of each
    process-wide random generator the reset drew from (``{"torch": ..., "numpy": ..., "python": ...}``, each
    compressed and base64-encoded: `simreel.sim.generators`), so that a replay's reset remakes the episode bit for bit;
    empty for a seeded episode (and in files of earlier simreel versions, whose readers ignore the field)."""
    seed_unchecked: bool = False
    """`seed` is the file's word only, not known to be the reset's: ManiSkill's RecordEpisode writes the env's last
    seed as ``episode_seed`` of a reset given none (a stale seed). An actions replay resets with it and keeps that
    reset only where it remakes the recorded initial state bit for bit, else restores that state and says so."""

    def __post_init__(self) -> None:
        """The chain, origin, provenance and verification as their records, also where given as their JSON
        (``chain={"start": 0, "position": 2}``), checked as a file's are."""
        for name, record in _RECORDS.items():
            value = getattr(self, name)
            if value is None or isinstance(value, Mapping):
                setattr(self, name, record.from_json(value or {}))
            elif not value.to_json():  # an empty record (a provenance whose scene was taken away): none, as read
                setattr(self, name, None)

    def to_json(self) -> dict[str, Any]:
        """Its fields as JSON values, new objects throughout (the JSON round trip copies; `dataclasses.asdict`'s deep
        copy before it doubled the cost, and every writer does this several times an episode)."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name in _RECORDS:
            fields[name] = {} if fields[name] is None else fields[name].to_json()
        return json.loads(json.dumps(fields, default=json_default))

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EpisodeMeta:
        """The metadata of JSON object `d`; `MetadataError` naming the first field that is missing or malformed."""
        kw = _fields_from_json(cls, d, "episode metadata")
        for name in ("index", "length", "env_idx"):
            if kw.get(name, 0) < 0:
                raise MetadataError(f"episode metadata: {name} is {kw[name]}, expected >= 0")
        return cls(**kw)


_RECORDS = {"chain": SceneChain, "origin": EpisodeOrigin, "provenance": EpisodeProvenance,
            "verification": EpisodeVerification}
"""`EpisodeMeta`'s fields that are typed records, each written as its JSON object (``{}`` where absent)."""


def new_recording_id() -> str:
    """A new `RecordingMeta.recording_id`: 32 random hex digits."""
    return uuid.uuid4().hex
