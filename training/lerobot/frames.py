"""An episode's rows as LeRobot frames: frame t is step t — ``observation.state`` the state the step's action was
taken in (per-state row t, the chosen fields flattened and joined), ``action`` its action, ``next.reward``,
``next.success`` its reward and success flag, ``next.done`` True where the step terminated or truncated the episode
and at its last step; each camera's frame t (per-state row t) for its video; ``timestamp`` t / fps; the index columns. The state after the last step (row T) has no frame.
Values are the recording's own, bit for bit (float32; the state fields' other dtypes must convert exactly)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simreel.errors import UsageError
from simreel.formats.base import EpisodeRows, block_rows
from simreel.model.fields import FieldSpec
from simreel.training.lerobot.layout import FrameFeature
from simreel.training.lerobot.videos import video_key

__all__ = ["FrameLayout", "EXACT_IN_FLOAT32"]

EXACT_IN_FLOAT32 = ("float32", "float16", "bool", "int8", "uint8", "int16", "uint16")
"""Dtypes whose every value float32 holds exactly: the state fields an export takes."""


class FrameLayout:
    """Which fields make which frame columns: `state` (per-state fields, joined into ``observation.state``), the
    step fields the file holds (actions, rewards, success, terminated, truncated), and `extras` (per-state fields as
    ``observation.environment_state``, per-step ``contact_forces`` as ``observation.contact_forces``)."""

    def __init__(self, state: Sequence[FieldSpec], fields: Sequence[FieldSpec],
                 extras: Sequence[FieldSpec] = (), cameras: Sequence[FieldSpec] = ()) -> None:
        for f in [*state, *extras]:
            if f.dtype not in EXACT_IN_FLOAT32:
                raise UsageError(f"{f.name} is {f.dtype}, which float32 does not hold exactly; choose fields of "
                                 f"{', '.join(EXACT_IN_FLOAT32)}")
        self.state = list(state)
        self.cameras = {video_key(f): f for f in cameras}
        """Camera fields by video key: their per-state rows 0 .. T-1 are the videos' frames."""
        self.extras = {"observation.environment_state": [f for f in extras if f.per_state],
                       "observation.contact_forces": [f for f in extras if not f.per_state]}
        held = {f.name: f for f in fields}
        self.actions = held["actions"]
        self.step_fields = [n for n in ("rewards", "success", "terminated", "truncated") if n in held]
        self.names = [f.name for f in (*self.state, *extras, *cameras)] + ["actions", *self.step_fields]
        self.features = self._features()

    def _features(self) -> list[FrameFeature]:
        features = [FrameFeature("observation.state", "float32", _width(self.state), _element_names(self.state))]
        features += [FrameFeature(key, "float32", _width(fs), _element_names(fs)) for key, fs in self.extras.items()
                     if fs]
        action_width = int(np.prod(self.actions.shape, dtype=np.int64))
        features.append(FrameFeature("action", "float32", action_width, [f"action[{k}]" for k in range(action_width)]))
        if "rewards" in self.step_fields:
            features.append(FrameFeature("next.reward", "float32", 1))
        if "success" in self.step_fields:
            features.append(FrameFeature("next.success", "bool", 1))
        features.append(FrameFeature("next.done", "bool", 1))
        features += [FrameFeature("timestamp", "float32", 1), FrameFeature("frame_index", "int64", 1),
                     FrameFeature("episode_index", "int64", 1), FrameFeature("index", "int64", 1),
                     FrameFeature("task_index", "int64", 1)]
        return features

    def frames(self, rows: EpisodeRows, *, fps: float, episode_index: int, first_index: int,
               task_index: int) -> dict[str, np.ndarray]:
        """The frame columns of the episode `rows` (read a block at a time), and each camera's frames (T, H, W, 3),
        by LeRobot key."""
        length = rows.length
        arrays = _episode_arrays(rows, self.names, [f.name for f in (*self.state, *self.extras[
            "observation.environment_state"], *self.cameras.values())])
        out = {"observation.state": _joined(arrays, self.state, length)}
        for key, camera in self.cameras.items():
            out[key] = arrays[camera.name][:length]
        for key, fs in self.extras.items():
            if fs:
                out[key] = _joined(arrays, fs, length)
        out["action"] = arrays["actions"].reshape(length, -1)
        if "rewards" in arrays:
            out["next.reward"] = arrays["rewards"]
        if "success" in arrays:
            out["next.success"] = arrays["success"]
        done = np.zeros(length, dtype=bool)
        for flag in ("terminated", "truncated"):
            if flag in arrays:
                done |= arrays[flag]
        done[-1] = True
        out["next.done"] = done
        frame_index = np.arange(length, dtype=np.int64)
        out["timestamp"] = (frame_index / fps).astype(np.float32)
        out["frame_index"] = frame_index
        out["episode_index"] = np.full(length, episode_index, dtype=np.int64)
        out["index"] = first_index + frame_index
        out["task_index"] = np.full(length, task_index, dtype=np.int64)
        return out


def _width(fields: Sequence[FieldSpec]) -> int:
    return sum(int(np.prod(f.shape, dtype=np.int64)) for f in fields)


def _element_names(fields: Sequence[FieldSpec]) -> list[str]:
    """``field[k]`` for every element of the joined fields, in order (a row-major flattening)."""
    return [f"{f.name}[{k}]" for f in fields for k in range(int(np.prod(f.shape, dtype=np.int64)))]


def _joined(arrays: dict[str, np.ndarray], fields: Sequence[FieldSpec], length: int) -> np.ndarray:
    """The fields' rows 0 .. length-1, each flattened, joined into (length, width) float32."""
    return np.concatenate([arrays[f.name][:length].reshape(length, -1).astype(np.float32) for f in fields], axis=1)


def _episode_arrays(rows: EpisodeRows, names: Sequence[str], per_state: Sequence[str]) -> dict[str, np.ndarray]:
    """Each field of `names` over the whole episode, read a block at a time: per-state fields their reset row and
    the rows after each step, per-step fields one row a step."""
    parts: dict[str, list[np.ndarray]] = {n: [] for n in names}
    if per_state:
        reset = rows.reset()
        for n in per_state:
            parts[n].append(reset[n])
    step = block_rows(rows.fields)
    for start in range(0, rows.length, step):
        block = rows.steps_of(names, start, min(rows.length, start + step))
        for n in names:
            parts[n].append(block[n])
    return {n: np.concatenate(p) for n, p in parts.items()}
