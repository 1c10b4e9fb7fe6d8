"""`RecordingDataset`: a `torch.utils.data.Dataset` of windows over simreel recordings (HDF5, MCAP) and ManiSkill
files, each sample one step of one episode. What a sample holds:

- each per-state feature (``obs/...``, ``env_states/...``, ``body_poses``): ``(history, *shape)``, the rows up to the
  step's own (the state its action was taken in), with ``<name>_is_pad``: True where the window reaches before the
  episode's reset (those rows repeat row 0);
- each per-step feature (``actions``, ``rewards``, ``success``, ``contact_forces``, ``info/...``): ``(horizon,
  *shape)``, the step's own row and the ones after it, with ``<name>_is_pad`` True past the episode's end (actions
  padded by the control mode: `simreel.training.windows.pad_actions`; other fields repeat the last row);
- ``episode`` (the episode's place in the set) and ``step`` (t).

Arrays are the recording's own values, dtype and all (numpy; a DataLoader's collate makes tensors of them). A
DataLoader asks for a whole batch at once (`RecordingDataset.__getitems__`: one fancy index per block the batch
touches); give it ``collate_fn=RecordingDataset.collate`` to make tensors of the batch's arrays without going
sample by sample.
`simreel.training.stats` normalizes. Rows are read a block at a time, each DataLoader worker through its own readers
(`simreel.training.blocks`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch.utils.data

from simreel.model.fields import FieldSpec
from simreel.options.checks import is_whole_number, options_with
from simreel.training.blocks import BlockCache
from simreel.training.episodes import EpisodeRef, SourceFile, chosen_episodes
from simreel.training.features import resolve_features, same_features
from simreel.training.options import SampleOptions
from simreel.training.windows import pad_action_batch, pads_with_zeros, window_rows

__all__ = ["RecordingDataset", "SampleBatch"]


class SampleBatch(list):
    """The samples `RecordingDataset.__getitems__` gives (a list of sample dicts, as `__getitem__` makes them), with
    `arrays`: each key's values for the whole batch, stacked (what `RecordingDataset.collate` turns into tensors)."""

    def __init__(self, arrays: dict[str, np.ndarray]) -> None:
        count = len(arrays["step"])
        super().__init__({k: int(v[i]) if k in ("episode", "step") else v[i] for k, v in arrays.items()}
                         for i in range(count))
        self.arrays = arrays


class RecordingDataset(torch.utils.data.Dataset):
    """Windows over the episodes of the recordings `inputs` names (files, folders, glob patterns), as `options` (a
    `SampleOptions`, or its fields as keywords) says: ``RecordingDataset("demos/", features=["obs", "actions"],
    history=2, horizon=8, episodes=EpisodeChoice(report="report.json", split="train"))``."""

    def __init__(self, inputs: str | Path | Sequence[str | Path], options: SampleOptions | None = None,
                 **overrides: Any) -> None:
        self.options = options_with(SampleOptions, options, overrides, 'RecordingDataset(inputs, horizon=8)')
        inputs = [inputs] if isinstance(inputs, (str, Path)) else list(inputs)
        self.episodes, self.files = chosen_episodes(inputs, self.options.episodes)
        self.fields = _chosen_fields(self.options.features, self.files, self.episodes)
        self.history, self.horizon = self.options.history, self.options.horizon
        self.starts = np.cumsum([0] + [e.length for e in self.episodes])
        """Sample number of each episode's step 0 (and the total, last)."""
        self.cache = BlockCache(self.fields, max_bytes=self.options.cache_bytes)
        self._lengths = np.array([e.length for e in self.episodes])
        self._where = [(e.path, e.index) for e in self.episodes]
        self._zero_pads = np.array([pads_with_zeros(self.control_mode(e), self.options.action_pad)
                                    for e in self.episodes])
        """Per episode: whether its actions past the end are zeros but for the last dimension (`pads_with_zeros`)."""

    def __len__(self) -> int:
        return int(self.starts[-1])

    def locate(self, sample: int) -> tuple[int, int]:
        """(episode number in `episodes`, step) of sample number `sample`."""
        if not is_whole_number(sample) or not -len(self) <= sample < len(self):
            raise IndexError(f"sample {sample!r}: the set has {len(self)} samples")
        sample = int(sample) % len(self)
        episode = int(np.searchsorted(self.starts, sample, side="right")) - 1
        return episode, sample - int(self.starts[episode])

    def __getitem__(self, sample: int) -> dict[str, Any]:
        return self.__getitems__([sample])[0]

    def __getitems__(self, samples: Sequence[int]) -> SampleBatch:
        """The samples numbered `samples`, read together (what a DataLoader asks for, a batch at a time)."""
        return SampleBatch(self.batch(samples))

    def batch(self, samples: Sequence[int]) -> dict[str, np.ndarray]:
        """The samples numbered `samples`, stacked: each key of a sample (`__getitem__`) with a first axis of
        len(samples)."""
        numbers = np.asarray(samples)
        if numbers.ndim != 1 or numbers.dtype.kind not in "iu" or len(numbers) and not (
                -len(self) <= numbers.min() and numbers.max() < len(self)):
            for sample in samples:
                self.locate(sample)  # raises IndexError, naming the sample
            numbers = numbers.astype(np.int64).reshape(-1)
        numbers = numbers.astype(np.int64) % max(len(self), 1)
        which = np.searchsorted(self.starts, numbers, side="right") - 1
        t = numbers - self.starts[which]
        out: dict[str, np.ndarray] = {}
        for field in self.fields:
            steps = self.history if field.per_state else self.horizon
            rows, is_pad = window_rows(t, self._lengths[which], steps, per_state=field.per_state)
            values = self.cache.gather(self._where, np.repeat(which, steps), field, rows.reshape(-1))
            values = values.reshape(len(t), steps, *field.shape)
            if field.name == "actions":
                values = pad_action_batch(values, is_pad, self._zero_pads[which])
            out[field.name], out[f"{field.name}_is_pad"] = values, is_pad
        out["episode"], out["step"] = which, t
        return out

    @staticmethod
    def collate(batch: list[dict[str, Any]]) -> dict[str, Any]:
        """A DataLoader's `collate_fn` for this set: the tensors torch's default collate makes, straight from the
        arrays of a batch read at once (`SampleBatch`); any other list of samples through the default collate."""
        if isinstance(batch, SampleBatch):
            return {k: torch.from_numpy(v) for k, v in batch.arrays.items()}
        return torch.utils.data.default_collate(batch)

    def control_mode(self, episode: EpisodeRef) -> str | None:
        """The control mode `episode`'s actions were given in."""
        return self.files[episode.path].meta.control_mode

    def close(self) -> None:
        """Close the readers this process opened."""
        self.cache.close()

    def __enter__(self) -> RecordingDataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _chosen_fields(features: Sequence[str], files: dict[str, SourceFile],
                   episodes: Sequence[EpisodeRef]) -> list[FieldSpec]:
    """The fields `features` choose, the same in every file the episodes come from (`same_features`)."""
    first_index = {}
    for e in episodes:
        first_index.setdefault(e.path, e.index)
    chosen: list[FieldSpec] | None = None
    first_path = ""
    for path, index in first_index.items():
        fields = resolve_features(features, files[path].fields, path=path, episode=index)
        if chosen is None:
            chosen, first_path = fields, path
        else:
            same_features(fields, chosen, path=path, first_path=first_path)
    assert chosen is not None  # there is at least one episode
    return chosen
