"""Normalization statistics of a training set's features, in one streaming pass (`compute_stats`): each feature's
count, mean, std, min and max per element, over every row of every episode of the set (a per-state feature's T + 1
rows, a per-step feature's T), merged a block at a time in float64 (Chan's parallel update), so memory stays flat
however long the set. `FeatureStats` saves them as JSON, loads them back and normalizes with them."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from simreel.errors import UsageError
from simreel.io.targets import check_output, write_text_atomic
from simreel.model.json_input import parse_json

if TYPE_CHECKING:  # the dataset imports torch; statistics of exported frames need none
    from simreel.training.dataset import RecordingDataset

__all__ = ["FeatureStats", "RunningStats", "block_moments", "compute_stats"]

_STATS = ("count", "mean", "std", "min", "max")


class RunningStats:
    """Count, mean, sum of squared deviations, min and max of rows of one shape, updated a block of rows at a time."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.count = 0
        self.mean = np.zeros(shape)
        self._m2 = np.zeros(shape)
        self.min = np.full(shape, np.inf)
        self.max = np.full(shape, -np.inf)

    def add(self, rows: np.ndarray) -> None:
        """Take `rows` (n, *shape) into the statistics."""
        if len(rows):
            self.merge(block_moments(rows))

    def merge(self, moments: tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:
        """Take the `block_moments` of a block of rows (taken elsewhere: another process) into the statistics, as
        `add` of those rows would, bit for bit."""
        n, mean, m2, low, high = moments
        total = self.count + n
        delta = mean - self.mean
        self.mean = self.mean + delta * (n / total)
        self._m2 = self._m2 + m2 + delta**2 * (self.count * n / total)
        self.count = total
        self.min, self.max = np.minimum(self.min, low), np.maximum(self.max, high)

    @property
    def std(self) -> np.ndarray:
        """The population standard deviation."""
        return np.sqrt(self._m2 / max(1, self.count))

    def to_json(self) -> dict[str, Any]:
        return {"count": self.count, "mean": self.mean.tolist(), "std": self.std.tolist(), "min": self.min.tolist(),
                "max": self.max.tolist()}


def block_moments(rows: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Count, mean, sum of squared deviations, min and max of a block of rows (n >= 1, *shape), in float64: what
    `RunningStats.merge` takes."""
    x = np.asarray(rows, dtype=np.float64)
    mean = x.mean(axis=0)
    return len(x), mean, ((x - mean) ** 2).sum(axis=0), x.min(axis=0), x.max(axis=0)


@dataclass
class FeatureStats:
    """Statistics by feature name: ``{"count": n, "mean": [...], "std": [...], "min": [...], "max": [...]}`` (arrays
    of the feature's row shape), and which episodes they were computed over."""

    features: dict[str, dict[str, Any]]
    episodes: list[dict[str, Any]] = field(default_factory=list)

    def array(self, name: str, stat: str) -> np.ndarray:
        """One statistic of one feature as an array; `UsageError` naming those there are."""
        if name not in self.features or stat not in _STATS:
            raise UsageError(f"no {stat} of {name!r}: the statistics hold {', '.join(_STATS)} of "
                             f"{', '.join(self.features)}")
        return np.asarray(self.features[name][stat], dtype=np.float64)

    def normalize(self, name: str, x: Any, *, eps: float = 1e-8) -> Any:
        """(x - mean) / (std + eps) of feature `name` (numpy arrays or torch tensors, any leading dimensions)."""
        mean, scale = self.array(name, "mean"), self.array(name, "std") + eps
        return (x - _like(mean, x)) / _like(scale, x)

    def unnormalize(self, name: str, y: Any, *, eps: float = 1e-8) -> Any:
        """The inverse of `normalize`."""
        mean, scale = self.array(name, "mean"), self.array(name, "std") + eps
        return y * _like(scale, y) + _like(mean, y)

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path:
        """Write the statistics as JSON to `path` (atomically; an existing file only with `overwrite`)."""
        check_output(path, overwrite=overwrite)
        write_text_atomic(path, json.dumps({"features": self.features, "episodes": self.episodes}, indent=1) + "\n")
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> FeatureStats:
        """Statistics `save` wrote; `UsageError` for a file that holds none."""
        doc = parse_json(Path(path).read_bytes(), path, what="it", error=lambda p, problem: UsageError(f"{p}: {problem}"),
                         then="not a statistics file written by FeatureStats.save")
        if not isinstance(doc, dict) or not isinstance(doc.get("features"), dict) or not all(
                isinstance(s, dict) and set(_STATS) <= set(s) for s in doc["features"].values()):
            raise UsageError(f"{path}: not a statistics file written by FeatureStats.save (no features with "
                             f"{', '.join(_STATS)})")
        return cls(doc["features"], doc.get("episodes", []))


def _like(a: np.ndarray, x: Any) -> Any:
    """`a` as `x`'s kind of array: a tensor of its dtype and device for a tensor, else float64 numpy."""
    if hasattr(x, "new_tensor"):
        return x.new_tensor(a)
    return a


def compute_stats(dataset: RecordingDataset) -> FeatureStats:
    """Each feature's statistics over every row of the set's episodes, reading each episode once, a block at a time."""
    running = {f.name: RunningStats(f.shape) for f in dataset.fields}
    cache = dataset.cache
    for episode in dataset.episodes:
        if any(f.per_state for f in dataset.fields):
            for name, rows in cache.block(episode.path, episode.index, -1).items():
                running[name].add(rows)
        for number in range(-(-episode.length // cache.rows)):
            for name, rows in cache.block(episode.path, episode.index, number).items():
                running[name].add(rows)
    return FeatureStats({name: r.to_json() for name, r in running.items()},
                        [{"file": e.path, "index": e.index, "verdict": e.verdict} for e in dataset.episodes])
