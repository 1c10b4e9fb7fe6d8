"""The statistics LeRobot keeps of each frame feature: per episode (min, max, mean, std, count and the quantiles
q01 .. q99, exact over the episode's frames) in the episodes parquet, and over the whole dataset in meta/stats.json
(min, max, mean and std exact over every frame, merged episode by episode in float64; the quantiles the
frame-weighted mean of the episodes' quantiles, as LeRobot's `aggregate_stats` makes them)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from simreel.training.lerobot.layout import QUANTILES
from simreel.training.stats import RunningStats

__all__ = ["episode_stats", "DatasetStats", "QUANTILE_KEYS"]

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


class DatasetStats:
    """The dataset's statistics of every feature, taken an episode at a time (`add`)."""

    def __init__(self) -> None:
        self._running: dict[str, RunningStats] = {}
        self._quantiles: dict[str, dict[str, np.ndarray]] = {}

    def add(self, frames: Mapping[str, np.ndarray], stats: Mapping[str, Mapping[str, np.ndarray]]) -> None:
        """Take one episode's frame columns and their `episode_stats`."""
        for key, values in frames.items():
            x = np.asarray(values).reshape(len(values), -1)
            running = self._running.setdefault(key, RunningStats(x.shape[1:]))
            running.add(x)
            weights = self._quantiles.setdefault(key, {q: np.zeros(x.shape[1:]) for q in QUANTILE_KEYS})
            for q in QUANTILE_KEYS:
                weights[q] += stats[key][q] * len(x)

    def document(self) -> dict[str, dict[str, Any]]:
        """meta/stats.json."""
        out = {}
        for key, running in self._running.items():
            entry = running.to_json()
            entry["count"] = [running.count]
            out[key] = {**entry, **{q: (w / running.count).tolist() for q, w in self._quantiles[key].items()}}
        return out
