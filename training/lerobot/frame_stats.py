"""The statistics LeRobot keeps of each frame feature: per episode (min, max, mean, std, count and the quantiles
q01 .. q99, exact over the episode's frames) in the episodes parquet, and over the whole dataset in meta/stats.json
(min, max, mean and std exact over every frame, merged episode by episode in float64; the quantiles the
frame-weighted mean of the episodes' quantiles, as LeRobot's `aggregate_stats` makes them)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.training.lerobot.layout import QUANTILES
from simreel.training.stats import RunningStats, block_moments

__all__ = ["episode_stats", "episode_moments", "DatasetStats", "QUANTILE_KEYS"]

QUANTILE_KEYS = tuple(f"q{round(q * 100):02d}" for q in QUANTILES)


def episode_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """The statistics of one feature's frames in one episode ((frames,) or (frames, width)), each of shape (width,)
    ((1,) for a plain column), as LeRobot's `compute_episode_stats` gives them."""
    x = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    out = {"min": x.min(axis=0), "max": x.max(axis=0), "mean": x.mean(axis=0), "std": x.std(axis=0),
           "count": np.array([len(x)], dtype=np.int64)}
    for key, q in zip(QUANTILE_KEYS, np.quantile(x, QUANTILES, axis=0), strict=True):
        out[key] = q
    return out


def episode_moments(frames: Mapping[str, np.ndarray], stats: Mapping[str, Mapping[str, np.ndarray]]
                    ) -> dict[str, tuple[tuple, dict[str, np.ndarray]]]:
    """What `DatasetStats.add` takes of one episode: each frame column's `block_moments` and its `episode_stats`
    quantiles. Small (a few numbers an element), so a worker process sends them to the one that merges them."""
    out = {}
    for key, values in frames.items():
        out[key] = (block_moments(np.asarray(values).reshape(len(values), -1)),
                    {q: stats[key][q] for q in QUANTILE_KEYS})
    return out


class DatasetStats:
    """The dataset's statistics of every feature, merged an episode at a time (`add`), in the episodes' order: the
    same numbers, bit for bit, whichever process took each episode's `episode_moments`."""

    def __init__(self) -> None:
        self._running: dict[str, RunningStats] = {}
        self._quantiles: dict[str, dict[str, np.ndarray]] = {}

    def add(self, moments: Mapping[str, tuple[tuple, Mapping[str, np.ndarray]]]) -> None:
        """Take one episode's `episode_moments`."""
        for key, (block, quantiles) in moments.items():
            count, shape = block[0], np.shape(block[1])
            self._running.setdefault(key, RunningStats(shape)).merge(block)
            weights = self._quantiles.setdefault(key, {q: np.zeros(shape) for q in QUANTILE_KEYS})
            for q in QUANTILE_KEYS:
                weights[q] += quantiles[q] * count
    def document(self) -> dict[str, dict[str, Any]]:
        """meta/stats.json."""
        out = {}
        for key, running in self._running.items():
            entry = running.to_json()
            entry["count"] = [running.count]
            out[key] = {**entry, **{q: (w / running.count).tolist() for q, w in self._quantiles[key].items()}}
        return out
