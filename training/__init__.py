"""simreel.training: the training room — recordings made into training data.

- `RecordingDataset(inputs, features=..., history=..., horizon=..., episodes=EpisodeChoice(...))`: a
  `torch.utils.data.Dataset` of observation histories and action chunks, with pad masks, over verified episodes
- `compute_stats(dataset)` → `FeatureStats`: each feature's mean, std, min and max in one streaming pass; saved and
  loaded as JSON, and what normalizes a sample

Importing this package imports neither torch nor mani_skill (each name is imported on first use).
"""

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {
    "simreel.training.dataset": ("RecordingDataset",),
    "simreel.training.options": ("SampleOptions", "EpisodeChoice", "DEFAULT_FEATURES"),
    "simreel.training.stats": ("FeatureStats", "compute_stats"),
}
"""Each public name and the module that defines it, imported on first use."""
_HOME_OF = {name: module for module, names in _HOMES.items() for name in names}

__all__ = sorted(_HOME_OF)


def __getattr__(name: str) -> Any:
    if name in _HOME_OF:
        return getattr(importlib.import_module(_HOME_OF[name]), name)
    raise AttributeError(f"module 'simreel.training' has no attribute {name!r}")
