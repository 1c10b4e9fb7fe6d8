"""`StepBlock`: consecutive rows of one episode's fields, as the recorder hands them to a writer and readers hand
them out; `join_blocks` puts blocks back together."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.errors import EpisodeLayoutError
from simreel.model.fields import FieldSpec


@dataclass(frozen=True)
class StepBlock:
    """Consecutive rows of one episode: flat field name → array of `rows` rows (see `episode_fields`).

    The recorder fills blocks of steps (each per-state field holding the states *after* those steps) and
    the reset row (per-state fields only, one row); writers consume them. `conform` checks a block
    against the field table.

    A recorder may leave some fields as it captured them, for its writer process to convert (`captured`: each
    (row source, its captures of these rows, env), the source a `simreel.sim.step_rows` class that makes
    (rows, num_envs, ...) arrays of the fields it `names`); `converted` makes them arrays.
    """

    arrays: Mapping[str, np.ndarray]
    rows: int
    captured: tuple[tuple[Any, list[Any], int], ...] = ()

    @classmethod
    def of(cls, arrays: Mapping[str, Any]) -> StepBlock:
        """A block of `arrays` (all with the same number of rows)."""
        arrays = {name: np.asarray(a) for name, a in arrays.items()}
        counts = {a.shape[0] if a.ndim else -1 for a in arrays.values()}
        if len(counts) > 1:
            raise EpisodeLayoutError(f"a step block mixes row counts {sorted(counts)}")
        return cls(arrays, counts.pop() if counts else 0)

    def __len__(self) -> int:
        return self.rows

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def get(self, name: str) -> np.ndarray | None:
        return self.arrays.get(name)

    def converted(self) -> StepBlock:
        """This block with every field an array: its captured fields converted."""
        if not self.captured:
            return self
        arrays = dict(self.arrays)
        for source, captures, env in self.captured:
            arrays.update({name: rows[:, env] for name, rows in source(captures).items()})
        return StepBlock(arrays, self.rows)

    def conform(self, fields: Iterable[FieldSpec], *, episode: int) -> dict[str, np.ndarray]:
        """The block's arrays for exactly `fields`, each cast to its dtype (no copy when it has it already:
        `_cast_keeping_values`); a field still `captured` counts as there, unchecked until it is converted.

        Raises `EpisodeLayoutError` naming the episode and the field when one is missing, has another row
        shape, holds a value its dtype cannot hold, or when the block holds a field the table does not list (it would
        be dropped silently).
        """
        captured = {name for source, _, _ in self.captured for name in source.names}
        out: dict[str, np.ndarray] = {}
        listed = set()
        for f in fields:
            listed.add(f.name)
            a = self.arrays.get(f.name)
            if a is None:
                if f.name in captured:
                    continue
                raise EpisodeLayoutError(f"episode {episode}: no {f.name} to write (the recording's layout lists it)")
            if a.shape != (self.rows, *f.shape):
                raise EpisodeLayoutError(
                    f"episode {episode}: {f.name} has shape {a.shape}, expected {(self.rows, *f.shape)} from the layout"
                )
            out[f.name] = _cast_keeping_values(a, np.dtype(f.dtype), f"episode {episode}: {f.name}")
        extra = sorted((set(self.arrays) | captured) - listed)
        if extra:
            raise EpisodeLayoutError(
                f"episode {episode}: {', '.join(extra[:3])} not in the recording's layout; describe every field in "
                "the RecordingMeta (state_layout, obs_layout, info_layout, contact_channels, pose_bodies)"
            )
        return out


def _cast_keeping_values(a: np.ndarray, dtype: np.dtype, what: str) -> np.ndarray:
    """`a` as `dtype` (no copy when it has it already) where the cast keeps every value: a type that holds all of
    `a`'s (``can_cast`` "safe"), a float type of the values rounded but none overflowed to infinity, an integer or bool
    type that holds each value exactly (0 and 1 for bool). Anything else is `EpisodeLayoutError` naming `what`: numpy's
    cast would store other values than given and say nothing (1e300 as inf, 2**40 as 0 in int32, 0.5 and NaN as True,
    a complex number's real part, text parsed as numbers)."""
    if a.dtype == dtype or np.can_cast(a.dtype, dtype, "safe"):
        return a.astype(dtype, copy=False)
    if a.dtype.kind not in "biuf":
        raise EpisodeLayoutError(f"{what} is {a.dtype}, not numbers of the layout's {dtype}; give values of that dtype")
    with np.errstate(over="ignore", invalid="ignore"):
        out = a.astype(dtype)
        changed = (np.isinf(out) & ~np.isinf(a)) if dtype.kind == "f" else ~(out.astype(a.dtype) == a)
    if changed.any():
        first = np.argwhere(changed)[0]
        raise EpisodeLayoutError(f"{what} holds {a[tuple(first)].item()!r} ({a.dtype}), which {dtype} cannot hold (it would be "
                                 f"stored as {out[tuple(first)].item()!r}); give values of that dtype")
    return out


def join_blocks(fields: Sequence[FieldSpec], reset: StepBlock, steps: Sequence[StepBlock]) -> dict[str, np.ndarray]:
    """The whole arrays of `fields` from an episode's reset row and its consecutive step blocks, in order: per-state
    fields are the reset row and then every block's rows (the states after those steps), per-step fields every
    block's rows. The inverse of `Episode.reset_block` + `Episode.steps_block`; the one place an episode read in
    blocks is put back together."""
    out: dict[str, np.ndarray] = {}
    for f in fields:
        parts = ([reset[f.name]] if f.per_state else []) + [b[f.name] for b in steps]
        out[f.name] = np.concatenate(parts) if parts else np.empty((0, *f.shape), f.dtype)
    return out


