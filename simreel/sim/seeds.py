"""The seeds ManiSkill takes: the one rule that `simreel record --seed` and `RecordWrapper.reset(seed=...)` check.

ManiSkill 3.0.1 seeds numpy's `RandomState` with each of them, which takes ints from 0 to 2**32 - 1 only; anything
else fails inside its reset, after a recorder has already ended the running episodes.
"""

from __future__ import annotations

import numbers
from typing import Any

__all__ = ["SEED_LIMIT", "is_seed"]

SEED_LIMIT = 2**32
"""ManiSkill's seeds are unsigned 32-bit numbers: from 0 to SEED_LIMIT - 1."""


def is_seed(value: Any) -> bool:
    """Whether `value` is one seed ManiSkill takes: an int (a numpy one too; not a bool, which is a flag given by
    mistake) from 0 to SEED_LIMIT - 1."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and 0 <= value < SEED_LIMIT
