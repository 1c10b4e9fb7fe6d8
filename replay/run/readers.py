"""The recordings a worker process holds open (`ReaderCache`)."""

from __future__ import annotations

from collections import OrderedDict

from simreel.formats import EpisodeReader, open_reader

__all__ = ["ReaderCache"]

_OPEN_READERS = 8
"""Recordings a worker keeps open (the work list visits files in turn, so few are ever needed again)."""


class ReaderCache:
    """The recordings a process has open, the `_OPEN_READERS` last used: a work list ordered by env key meets each
    file in runs, and thousands of files must not mean thousands of open handles."""

    def __init__(self) -> None:
        self._readers: OrderedDict[str, EpisodeReader] = OrderedDict()

    def get(self, path: str) -> EpisodeReader:
        reader = self._readers.get(path)
        if reader is None:
            reader = self._readers[path] = open_reader(path)
            if len(self._readers) > _OPEN_READERS:
                self._readers.popitem(last=False)[1].close()
        self._readers.move_to_end(path)
        return reader

    def __len__(self) -> int:
        return len(self._readers)

    def close(self) -> None:
        while self._readers:
            self._readers.popitem()[1].close()
