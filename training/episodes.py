"""Which episodes a training set holds: the recordings its inputs name (files, folders, patterns, as `simreel replay`
takes them), kept by a replay report's verdicts (verified only, by default, when a report is given), and split by
episode with a seed (`split_episodes`): no episode lends steps to both sides of a split."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simreel.datasets.dataset import report_verdicts
from simreel.datasets.inputs import expand_inputs
from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.model.fields import FieldSpec, episode_fields
from simreel.model.meta import RecordingMeta
from simreel.training.options import EpisodeChoice
from simreel.verdicts.report_file import read_verdicts

__all__ = ["EpisodeRef", "SourceFile", "select_episodes", "split_episodes", "chosen_episodes", "episode_count"]


@dataclass(frozen=True)
class EpisodeRef:
    """One episode of a training set: its recording, its index there, its steps and its replay verdict (None: no
    report was given)."""

    path: str
    index: int
    length: int
    verdict: str | None = None


@dataclass
class SourceFile:
    """A recording a training set reads: its metadata and field table, read once when the set is made."""

    path: str
    meta: RecordingMeta
    fields: list[FieldSpec]


def chosen_episodes(inputs: Sequence[str | Path], choice: EpisodeChoice) -> tuple[list[EpisodeRef],
                                                                                  dict[str, SourceFile]]:
    """(episodes, their files by path): those of the recordings `inputs` name that `choice` takes."""
    every, files = select_episodes(inputs, report=choice.report, keep=choice.keep)
    episodes = split_episodes(every, choice.split, val_fraction=choice.val_fraction, seed=choice.seed)
    if not episodes:
        raise UsageError(f"split={choice.split!r} holds no episode of the {len(every)} there are; use split=None")
    return episodes, files


def select_episodes(inputs: Sequence[str | Path], *, report: str | Path | None = None,
                    keep: Sequence[str] = ("exact", "within_tolerance")) -> tuple[list[EpisodeRef],
                                                                                   dict[str, SourceFile]]:
    """(episodes, their files by path) of the recordings `inputs` name, in the order given, each file's episodes by
    index. Episodes without steps are left out (no sample starts in them). With `report` (a `simreel replay
    --report` file), only the episodes whose verdict is one of `keep`; `UsageError` when the report does not cover a
    file, or the file changed since it was replayed (`report_verdicts`)."""
    found = None if report is None else read_verdicts(report)
    episodes: list[EpisodeRef] = []
    files: dict[str, SourceFile] = {}
    for path, _ in expand_inputs(inputs):
        with open_reader(path) as reader:
            reader.refuse_damaged("read for training")
            verdicts = {} if found is None else report_verdicts(path, found.verdicts, found.files, report)
            files[str(path)] = SourceFile(str(path), reader.meta, episode_fields(reader.meta))
            for m in reader.episodes:
                verdict = verdicts.get(m.index)
                if m.length and (found is None or verdict in keep):
                    episodes.append(EpisodeRef(str(path), m.index, m.length, verdict))
    if not episodes:
        kept = f" with the verdict {' or '.join(keep)} in {report}" if report is not None else " with steps"
        raise UsageError(f"no episode{kept} in {', '.join(map(str, inputs))}")
    return episodes, files


def episode_count(paths: Sequence[str | Path]) -> int:
    """How many episodes the recordings `paths` hold, with or without steps (what a report's verdicts left out is
    this less what was chosen)."""
    total = 0
    for path in paths:
        with open_reader(path) as reader:
            total += len(reader.episodes)
    return total


def split_episodes(episodes: Sequence[EpisodeRef], split: str | None, *, val_fraction: float,
                   seed: int) -> list[EpisodeRef]:
    """The episodes of one side of a split (`split` "train" or "val"; None: all), in their order: the episodes are
    shuffled with `seed` and the first `val_fraction` of them (at least one, where there are two or more) go to
    "val". The same episodes and seed give the same split in every process."""
    if split is None:
        return list(episodes)
    order = np.random.default_rng(seed).permutation(len(episodes))
    n_val = min(len(episodes) - 1, max(1, round(val_fraction * len(episodes)))) if len(episodes) > 1 else 0
    val = set(order[:n_val].tolist())
    return [e for k, e in enumerate(episodes) if (k in val) == (split == "val")]
