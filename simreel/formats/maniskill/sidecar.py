"""ManiSkill's JSON sidecar (``<name>.json`` beside ``<name>.h5``), written and read here, side by side.

Its document, as ManiSkill 3.0.1's RecordEpisode writes it::

    {"env_info": {"env_id": ..., "env_kwargs": {gym.make kwargs as given}, "max_episode_steps": ...},
     "commit_info": {...} | null, "source_type": ..., "source_desc": ...,   (the last two only when given)
     "episodes": [{"episode_id", "episode_seed", "control_mode", "elapsed_steps",
                   "reset_kwargs": {"seed", "options"} ({} for num_envs > 1), "success", "fail"}, ...]}

simreel writes it beside its HDF5 recordings so ManiSkill's tools (`replay_trajectory`, its dataset loaders)
read them; simreel itself needs it only for ManiSkill's own files (`simreel.formats.maniskill.reader`).

`SidecarFile` keeps it current while simreel records: it is written whole when the recording starts, and each
committed episode is added in place by one write that also rewrites the closing brackets, so the file is
valid JSON after every commit, costs the same for the 10th episode as for the 10,000th, and lags the `.h5`
by at most the commit in flight (the `.h5` is flushed first). The file carries spaces after its closing
brace (JSON allows them), reserved before each commit, so adding an entry never needs new disk space and a
full disk refuses the commit before the `.h5` is touched; `close` cuts them off.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.errors import RecordingFileError
from simreel.formats.maniskill.layout import sidecar_path
from simreel.io.targets import write_text_atomic
from simreel.model.json_input import json_value
from simreel.model.meta import EpisodeMeta, RecordingMeta, json_default

__all__ = ["Sidecar", "SidecarFile", "sidecar_document", "write_sidecar"]

_TAIL = b"\n  ]\n}\n"
_PAD = 4096
"""Spaces reserved after the closing brace at a time."""


# ------------------------------------------------------------------------------------------------ writing
def sidecar_document(meta: RecordingMeta, episodes: list[EpisodeMeta]) -> dict[str, Any]:
    """The sidecar's JSON of a simreel recording: `env_info` (env id, gym.make kwargs, time limit) and one
    entry per committed episode. A render backend of "none" (state-only, or none known: a ManiSkill file that named
    none) is left out: ManiSkill's `replay_trajectory` passes the kwargs on, and with "none" its `-o rgb` re-rendering
    of the demos fails; without it ManiSkill picks the machine's device."""
    env_kwargs = {
        **meta.env_kwargs,
        "obs_mode": meta.obs_mode,
        "control_mode": meta.control_mode,
        "sim_backend": meta.sim_backend,
        "render_backend": None if meta.render_backend == "none" else meta.render_backend,
        "reward_mode": meta.reward_mode,
    }
    return {
        "env_info": {
            "env_id": meta.env_id,
            "env_kwargs": {k: v for k, v in env_kwargs.items() if v is not None},
            "max_episode_steps": meta.max_episode_steps,
        },
        **_source(meta),
        "episodes": [_episode_entry(meta, e) for e in episodes],
    }


def _source(meta: RecordingMeta) -> dict[str, Any]:
    """``source_type`` and ``source_desc``: a ManiSkill file's own (a copy of motion-planning demos stays one),
    else simreel and the command that made the recording."""
    given = meta.source if meta.source.get("format") == "maniskill" else {}
    return {"source_type": given.get("source_type", "simreel"), "source_desc": given.get("source_desc", meta.command)}


def _episode_entry(meta: RecordingMeta, e: EpisodeMeta) -> dict[str, Any]:
    return {
        "episode_id": e.index,
        "episode_seed": e.seed,
        "reset_kwargs": {"seed": e.seed, **({"options": e.reset_options} if e.reset_options else {})},
        "control_mode": meta.control_mode,
        "elapsed_steps": e.length,
        "success": e.success,
    }


def write_sidecar(path: Path, meta: RecordingMeta, episodes: list[EpisodeMeta]) -> None:
    """(Re)write the sidecar of the recording `path` atomically."""
    doc = sidecar_document(meta, episodes)
    write_text_atomic(sidecar_path(path), json.dumps(doc, indent=2, default=json_default))


class SidecarFile:
    """The sidecar at `path`, kept open and extended by one in-place write per committed episode."""

    def __init__(self, path: Path, meta: RecordingMeta) -> None:
        self.meta = meta
        head = json.dumps({k: v for k, v in sidecar_document(meta, []).items() if k != "episodes"}, indent=2,
                          default=json_default)
        head_bytes = (head[: head.rindex("\n}")] + ',\n  "episodes": [').encode()
        write_text_atomic(path, (head_bytes + _TAIL).decode())
        self._fd = os.open(path, os.O_RDWR)
        self._end = len(head_bytes)
        """Where the next entry goes (the closing brackets follow it)."""
        self._size = self._end + len(_TAIL)
        """The file's size: the document, then reserved spaces."""
        self._count = 0

    def _entry(self, episode: EpisodeMeta) -> bytes:
        entry = json.dumps(_episode_entry(self.meta, episode), default=json_default)
        return ((",\n    " if self._count else "\n    ") + entry).encode()

    def reserve(self, episode: EpisodeMeta) -> None:
        """Make sure adding `episode` needs no new disk space (`OSError` when the disk has none left)."""
        need = self._end + len(self._entry(episode)) + len(_TAIL)
        if need > self._size:
            grow = need - self._size + _PAD
            os.pwrite(self._fd, b" " * grow, self._size)
            self._size += grow

    def append(self, episode: EpisodeMeta) -> None:
        """Add `episode` to the list: one write of the entry and the closing brackets after it."""
        self.reserve(episode)
        data = self._entry(episode)
        os.pwrite(self._fd, data + _TAIL, self._end)
        self._end += len(data)
        self._count += 1

    def close(self) -> None:
        """Cut off the reserved spaces and close the file."""
        if self._fd >= 0:
            try:
                os.ftruncate(self._fd, self._end + len(_TAIL))
            finally:
                os.close(self._fd)
                self._fd = -1


# ------------------------------------------------------------------------------------------------ reading
@dataclass(frozen=True)
class Sidecar:
    """A ManiSkill sidecar as read: the env it names, its episodes, and where the data came from."""

    path: Path
    env_id: str
    env_kwargs: dict[str, Any]
    max_episode_steps: int | None
    episodes: list[dict[str, Any]]
    source: dict[str, Any] = field(default_factory=dict)
    """``source_type``, ``source_desc``, ``commit_info`` as the file gives them."""
    other: dict[str, Any] = field(default_factory=dict)
    """Keys of the top level and of ``env_info`` (as ``env_info.<key>``) that ManiSkill 3.0.1 does not write and
    the reader does not map (another tool's additions), with their values."""

    @classmethod
    def read(cls, h5_path: Path) -> Sidecar:
        """The sidecar beside `h5_path`; `RecordingFileError` naming it when it is missing or malformed."""
        path = sidecar_path(h5_path)
        if not path.is_file():
            raise RecordingFileError(
                h5_path, f"a ManiSkill trajectory file (traj_N groups) without its JSON sidecar: {path} is missing "
                "(ManiSkill's RecordEpisode and replay_trajectory write it beside the .h5; copy it along)"
            )
        try:
            doc = json_value(path.read_bytes(), "it")
        except (OSError, ValueError) as e:
            raise RecordingFileError(path, f"unreadable ManiSkill sidecar ({e})") from None
        return cls._from_document(path, doc)

    @classmethod
    def _from_document(cls, path: Path, doc: Any) -> Sidecar:
        info = doc.get("env_info") if isinstance(doc, Mapping) else None
        if not isinstance(info, Mapping) or not isinstance(info.get("env_id"), str):
            raise RecordingFileError(
                path, "a ManiSkill sidecar without env_info.env_id (RecordEpisode writes none when the env was not "
                "made with gym.make): simreel cannot tell which env to rebuild"
            )
        episodes = doc.get("episodes")
        if not isinstance(episodes, list) or not all(isinstance(e, Mapping) and "episode_id" in e for e in episodes):
            raise RecordingFileError(path, "a ManiSkill sidecar whose `episodes` is not a list of {episode_id, ...}")
        kwargs = info.get("env_kwargs") or {}
        if not isinstance(kwargs, Mapping):
            raise RecordingFileError(path, f"env_info.env_kwargs is {type(kwargs).__name__}, expected an object")
        _check_types(path, "env_info.env_kwargs", kwargs, _KWARG_TYPES)
        steps = _time_limit(path, info.get("max_episode_steps"))
        source = {k: doc[k] for k in ("source_type", "source_desc", "commit_info") if doc.get(k) is not None}
        other = {k: v for k, v in doc.items() if k not in _DOCUMENT_KEYS}
        other.update({f"env_info.{k}": v for k, v in info.items() if k not in _ENV_INFO_KEYS})
        return cls(path, info["env_id"], dict(kwargs), steps, [_episode_read(path, i, e) for i, e in enumerate(episodes)],
                   source, other)


def _time_limit(path: Path, steps: Any) -> int | None:
    """``env_info.max_episode_steps``: a whole number ≥ 1, or null where the env had no time limit. Anything else is
    `RecordingFileError`: read as no limit, or as -1, the replay's env would end its episodes elsewhere than the
    recording's, and the replay be called diverged for a fault of the file."""
    if steps is None:
        return None
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise RecordingFileError(path, f"env_info.max_episode_steps is {json.dumps(steps, default=str)[:60]}, "
                                       f"expected {_WHOLE} >= 1 or null")
    return steps


_DOCUMENT_KEYS = ("env_info", "episodes", "source_type", "source_desc", "commit_info")
_ENV_INFO_KEYS = ("env_id", "env_kwargs", "max_episode_steps")
"""The sidecar's top-level and ``env_info`` keys as ManiSkill 3.0.1 writes them (`Sidecar.other`: the rest)."""


_WHOLE = "a whole number"
_TEXT = "a string"
_OBJECT = "an object"
_KWARG_TYPES = {"obs_mode": _TEXT, "control_mode": _TEXT, "reward_mode": _TEXT, "sim_backend": _TEXT,
                "render_backend": _TEXT, "num_envs": _WHOLE, "sim_config": _OBJECT}
"""The env_kwargs the reader uses, and what each must be (absent or null is allowed: the env's default)."""
_EPISODE_TYPES = {"episode_id": _WHOLE, "elapsed_steps": _WHOLE, "control_mode": _TEXT, "reset_kwargs": _OBJECT}
"""The keys of an episode entry the reader uses (besides seeds and success, whose oddities it notes, not refuses)."""


def _episode_read(path: Path, i: int, entry: Mapping[str, Any]) -> dict[str, Any]:
    """Entry `i` of the sidecar's `episodes`, its keys checked (`RecordingFileError` naming the entry and the key
    otherwise: a hand-edited or foreign sidecar), its ``episode_id`` an int (ManiSkill's tools accept a digit
    string too, as they only format it into ``traj_<id>``)."""
    entry = dict(entry)
    if isinstance(entry["episode_id"], str) and entry["episode_id"].isascii() and entry["episode_id"].isdigit():
        entry["episode_id"] = int(entry["episode_id"])
    where = f"episodes[{i}]"
    _check_types(path, where, entry, _EPISODE_TYPES)
    if entry["episode_id"] is None or entry["episode_id"] < 0:
        raise RecordingFileError(path, f"{where}.episode_id is {entry['episode_id']!r}, expected a whole number >= 0")
    _check_types(path, f"{where}.reset_kwargs", entry.get("reset_kwargs") or {}, {"options": _OBJECT})
    return entry


def _check_types(path: Path, where: str, values: Mapping[str, Any], types: Mapping[str, str]) -> None:
    """`RecordingFileError` for the first of `types`' keys whose value in `values` is neither absent, null, nor
    of its kind."""
    kinds = {_WHOLE: lambda v: isinstance(v, int) and not isinstance(v, bool), _TEXT: lambda v: isinstance(v, str),
             _OBJECT: lambda v: isinstance(v, Mapping)}
    for key, kind in types.items():
        value = values.get(key)
        if value is not None and not kinds[kind](value):
            raise RecordingFileError(path, f"{where}.{key} is {json.dumps(value, default=str)[:60]}, expected {kind}")
