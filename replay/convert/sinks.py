"""Where a conversion's rows go as they are converted: `WrittenEpisode` (into the output, a scratch recording or a
collected episode, hashed for the check of what is written, committed or left out by ``keep``), `RenderedRows` (a
re-render's output rows: the recorded ones with the rendered observations) and `TrackingSink` (a control-mode
conversion's tracking errors, block by block)."""

from __future__ import annotations

import numpy as np

from simreel.datasets.digests import FieldHashes
from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances
from simreel.model.meta import EpisodeMeta
from simreel.replay.convert.job import ConvertResult
from simreel.replay.convert.tracking import EndEffector, TrackingBlocks
from simreel.replay.report.report import EpisodeReport
from simreel.replay.run.engine import EpisodeReplayer
from simreel.replay.run.output import EpisodeStream, ScratchEpisode
from simreel.replay.run.sinks import BlockSink, Collected
from simreel.replay.run.worklist import WorkItem

__all__ = ["RenderedRows", "TrackingSink", "WrittenEpisode"]


class WrittenEpisode(BlockSink):
    """Hands each converted block on to `then` (an `EpisodeStream` into the output or a scratch recording, or a
    `Collected` episode), hashing it (`hashes`) for the check of what is written and noting (success, truncated) at
    the last step so far (`last`), for `keep`; `finish` then commits the episode or leaves it out."""

    def __init__(self, then: EpisodeStream | Collected) -> None:
        self.then = then
        self.start()

    def start(self) -> None:
        self.hashes = FieldHashes()
        self.last: tuple[bool | None, bool | None] = (None, None)
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.hashes.add(replayed, replayed.arrays)
        self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.hashes.add(replayed, replayed.arrays)
        if replayed.rows:
            self.last = _last_flags(replayed.get("success"), replayed["truncated"])
        self.then.steps(first, recorded, replayed)

    def discard(self) -> None:
        """Drop what was written of the episode (an error or Ctrl-C stopped its conversion)."""
        if isinstance(self.then, EpisodeStream):
            self.then.discard()

    def finish(self, item: WorkItem, report: EpisodeReport, meta: EpisodeMeta, length: int,
               keep: tuple[str, ...]) -> ConvertResult:
        """The episode's result: left out by `keep` (what was written of it discarded), or committed with `meta`
        (the scratch recording's path with it), or collected whole."""
        why = _left_out(report, self.last, keep)
        if why:
            self.discard()
            return ConvertResult(item, report, left_out=why)
        digests = self.hashes.digests()
        if isinstance(self.then, Collected):
            return ConvertResult(item, report, self.then.episode(meta), digests=digests)
        self.then.commit(meta, length)
        scratch = self.then.path if isinstance(self.then, ScratchEpisode) else None
        return ConvertResult(item, report, scratch=scratch, digests=digests)


class RenderedRows(BlockSink):
    """The output rows of a re-render as they are replayed, handed on to `then`: the recorded rows as they are,
    with the replay's observations in place of the recorded ones, and the rewards and flags the recording lacks
    taken from the replay (recomputed from the restored states)."""

    _FILLED = ("rewards", "success", "fail")

    def __init__(self, then: BlockSink) -> None:
        self.then = then

    def start(self) -> None:
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.then.reset(recorded, self._output(recorded, replayed, ()))

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.then.steps(first, recorded, self._output(recorded, replayed, self._FILLED))

    @staticmethod
    def _output(recorded: StepBlock, replayed: StepBlock, filled: tuple[str, ...]) -> StepBlock:
        arrays = {k: a for k, a in recorded.arrays.items() if not k.startswith("obs/")}
        arrays.update({k: a for k, a in replayed.arrays.items()
                       if k.startswith("obs/") or (k in filled and k not in arrays)})
        return StepBlock(arrays, recorded.rows)


class TrackingSink(BlockSink):
    """Takes the tracking errors of each block of a control-mode conversion (`TrackingBlocks`, bound to the
    replayer's end effector when the episode's replay starts, after its reset) and hands the block on to `then`."""

    def __init__(self, replayer: EpisodeReplayer, tolerances: Tolerances, initial: bool, then: BlockSink) -> None:
        self._args = (replayer, tolerances, initial)
        self.then = then

    def start(self) -> None:
        replayer, tolerances, initial = self._args
        self.blocks = TrackingBlocks(EndEffector(replayer.u), tolerances, initial=initial)
        self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.reset(recorded, replayed)
        self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.steps(recorded, replayed)
        self.then.steps(first, recorded, replayed)


def _last_flags(success: np.ndarray | None, truncated: np.ndarray) -> tuple[bool | None, bool | None]:
    """(success, truncated) at the last of these steps; None where there is no step (or no success flag)."""
    if not len(truncated):
        return None, None
    return (None if success is None else bool(success[-1])), bool(truncated[-1])


def _left_out(report: EpisodeReport, last: tuple[bool | None, bool | None], keep: tuple[str, ...]) -> str:
    """Why `keep` leaves the episode out ("" to write it), given (success, truncated) at its last step
    (`_last_flags`)."""
    success, truncated = last
    if "all" in keep:
        return ""
    if not report.ok:
        return f"not verified ({report.verdict})"
    if "success" in keep and not success:
        return "no success at its last step"
    if "not_truncated" in keep and truncated:
        return "truncated (time limit)"
    return ""
