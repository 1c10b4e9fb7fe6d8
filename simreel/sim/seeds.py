"""The seeds ManiSkill takes: the one rule that `simreel record --seed`, `simreel audit --seed` and
`RecordWrapper.reset(seed=...)` check.

ManiSkill 3.0.1 seeds numpy's `RandomState` with each of them, which takes ints from 0 to 2**32 - 1 only; anything
else fails inside its reset, after a recorder has already ended the running episodes.
"""

from __future__ import annotations

import numbers
from typing import Any

from simreel.errors import UsageError

__all__ = ["SEED_LIMIT", "is_seed", "check_seed_span"]

SEED_LIMIT = 2**32
"""ManiSkill's seeds are unsigned 32-bit numbers: from 0 to SEED_LIMIT - 1."""


def is_seed(value: Any) -> bool:
    """Whether `value` is one seed ManiSkill takes: an int (a numpy one too; not a bool, which is a flag given by
    mistake) from 0 to SEED_LIMIT - 1."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and 0 <= value < SEED_LIMIT


def check_seed_span(first: Any, last: int, run: str, count: str) -> None:
    """`UsageError` unless a `run` ("run", "audit") that uses seeds `first` to `last` (its count of episodes, option
    `count`, decides how many) stays within the seeds ManiSkill takes: checked before anything starts, as a seed
    past them fails inside a reset."""
    if not (is_seed(first) and is_seed(last)):
        raise UsageError(f"--seed {first}: this {run} would use seeds {first} to {last}, but ManiSkill takes seeds "
                         f"from 0 to {SEED_LIMIT - 1}; choose a seed, or fewer episodes ({count}), that keeps them in "
                         "that range")
