"""`EpisodeSelection`: episode indices named as ranges (``--episodes 0,3-7``), kept as ranges."""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Collection, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.options.checks import is_whole_number


@dataclass(frozen=True)
class EpisodeSelection:
    """Episode indices named as a list of ranges, ``0,3-7`` (``--episodes``), kept as those ranges: what it costs
    depends on the text and on the episodes a file has, never on the numbers (``0-99999999999`` is two of them).

    It is iterated (the indices in the order named, a range one index at a time, repeats kept), asked whether it
    holds an index and whether it names any; `pick` and `missing` answer for a file's episodes in time and memory
    bounded by those. Nothing asks for its length or a list of all it names: that is what a huge range must not
    build.
    """

    ranges: tuple[tuple[int, int], ...]
    """(first, last) of each part, in the order named; first <= last."""

    @classmethod
    def parse(cls, text: str) -> EpisodeSelection:
        """``"0,3-7"`` → ranges (0, 0) and (3, 7); an empty part is skipped. `ValueError` for a part that is not N or
        N-M with M >= N, each a number of ASCII digits only (no sign, no ``1_0``: Python's int() takes those)."""
        ranges = []
        for part in text.split(","):
            if part.strip():
                first, _, last = part.partition("-") if "-" in part else (part, "", part)
                lo, hi = _digits(first), _digits(last)
                if hi < lo:
                    raise ValueError(f"range {part.strip()!r} runs backwards")
                ranges.append((lo, hi))
        return cls(tuple(ranges))

    @classmethod
    def of(cls, value: EpisodeSelection | str | Iterable[int] | None, *,
           name: str = "episodes") -> EpisodeSelection | None:
        """`value` as a selection: None stays None, text is parsed, indices (a library caller's list, a report's)
        are one range each, in their order. Anything else is `UsageError` saying what to give: a number alone, a
        bool, a float, a negative index (the text takes none either), text that `parse` refuses. `name`: the option
        it was given as, for the message."""
        if value is None or isinstance(value, EpisodeSelection):
            return value
        try:
            if isinstance(value, str):
                return cls.parse(value)
            if isinstance(value, (bytes, bytearray)) or not isinstance(value, Iterable):
                raise ValueError("not a list of indices")
            return cls(tuple((i, i) for i in map(_episode_index, value)))
        except ValueError as e:
            raise UsageError(f"{name}={value!r}: {e}; give episode indices, ints >= 0 (e.g. [0, 3]), their text as "
                             "--episodes takes it (\"0,3-7\"), or None (all)") from None

    def __iter__(self) -> Iterator[int]:
        for lo, hi in self.ranges:
            yield from range(lo, hi + 1)

    def __contains__(self, index: object) -> bool:
        return any(lo <= index <= hi for lo, hi in self.ranges)  # type: ignore[operator]

    def __bool__(self) -> bool:
        return bool(self.ranges)

    def __str__(self) -> str:
        """As it would be typed: ``0,3-7``."""
        return ",".join(str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in self.ranges)

    def to_json(self) -> str:
        """Its text (`__str__`), which `of` reads back: a report keeps it whatever the numbers."""
        return str(self)

    def pick(self, have: Iterable[int]) -> list[int]:
        """The indices named that are in `have` (a file's episodes), each once, in the order named: a range longer
        than `have` is walked through `have`, so the work is bounded by `have`, not by the range."""
        held = set(have)
        present = sorted(held)
        found: dict[int, None] = {}
        for lo, hi in self.ranges:
            if hi - lo < len(present):
                found.update((i, None) for i in range(lo, hi + 1) if i in held)
            else:
                found.update((i, None) for i in present[bisect.bisect_left(present, lo):bisect.bisect_right(present, hi)])
        return list(found)

    def missing(self, have: Collection[int], limit: int) -> list[int]:
        """The first `limit` indices named that `have` lacks, each once, in the order named: a range walked past
        `have` and those found already yields a lacking index at least every ``len(have) + limit + 1`` steps, so the
        work is bounded by `have` and `limit`, not by the range."""
        lacking: dict[int, None] = {}
        for lo, hi in self.ranges:
            walk = (i for i in range(lo, hi + 1) if i not in have and i not in lacking)
            lacking.update((i, None) for i in itertools.islice(walk, limit - len(lacking)))
            if len(lacking) >= limit:
                break
        return list(lacking)


def _episode_index(value: Any) -> int:
    """An episode index a library caller gave: an int (a numpy int too) >= 0, else `ValueError` (a bool too: True
    is not episode 1)."""
    if not is_whole_number(value):
        raise ValueError(f"{value!r} is not a whole number")
    if value < 0:
        raise ValueError(f"{value} is negative")
    return int(value)


def _digits(text: str) -> int:
    """The number `text` writes (spaces around it allowed) in ASCII digits only; `ValueError` for anything else."""
    text = text.strip()
    if not (text.isascii() and text.isdigit()):
        raise ValueError(f"{text!r} is not a number of digits")
    return int(text)


def parse_index_ranges(text: str) -> EpisodeSelection:
    """`--episodes`: `"0,3-7"` → the selection of 0 and 3 to 7, kept as ranges (`EpisodeSelection`), so a huge range
    costs no memory; `UsageError` unless every part is N or N-M (M >= N) in digits."""
    try:
        return EpisodeSelection.parse(text)
    except ValueError:
        raise UsageError(f"bad episode list {text!r}: expected e.g. 0,3-7") from None
