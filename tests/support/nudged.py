"""A copy of a recording whose episode `episode` had one action nudged, so that its replay diverges while the
other episodes replay exactly: the recording a test of a replay report's verdicts starts from."""

from __future__ import annotations

from pathlib import Path

from simreel.formats import open_reader, open_writer


def nudged_copy(source: Path, out: Path, *, episode: int = 1, step: int = 5, by: float = 0.5) -> Path:
    """Copy `source` to `out` with `by` added to episode `episode`'s action at `step`."""
    with open_reader(source) as r, open_writer(out, r.meta) as w:
        for m in r.episodes:
            copied = r.read_episode(m.index)
            copied.actions[step] += by * (m.index == episode)
            w.write_episode(copied)
    return out
