"""Where a block replay's rows go (`simreel.replay.run.engine.EpisodeReplayer.replay_rows`): the `BlockSink`
interface, `Collected` (the replayed episode put together whole) and `VerifySink` (each block compared with its
recorded one as it comes, and handed on)."""

from __future__ import annotations

import dataclasses

import numpy as np

from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.fields import FLAG_FIELDS
from simreel.model.meta import ContactChannel, EpisodeMeta
from simreel.verdicts.compare import BlockComparison, CompareScope, EpisodeComparison

__all__ = ["BlockSink", "Collected", "VerifySink"]


class BlockSink:
    """Where a block replay (`EpisodeReplayer.replay_rows`) hands each recorded block with its replay. Subclasses
    must not keep a block's arrays beyond the call unless they mean to hold the episode (`Collected`)."""

    def start(self) -> None:
        """A replay of the episode begins (again, if the engine had to rebuild its env: drop what came before)."""

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        """Row 0 of the per-state fields, recorded and replayed."""

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        """The block of steps `first`.. , recorded and replayed."""

    def info_not_returned(self, keys: list[str]) -> None:
        """After the last block: the recorded info `keys` the replaying task returned at no step (their replayed rows
        hold zeros, as the recorder writes an absent entry, not values it produced)."""


class Collected(BlockSink):
    """Keeps every replayed block, to put the replayed episode together (`episode`); `obs=False` drops the
    observations."""

    def __init__(self, *, obs: bool = True) -> None:
        self.obs = obs
        self.start()

    def start(self) -> None:
        self._reset: StepBlock | None = None
        self._blocks: list[StepBlock] = []
        self.info_unreturned: list[str] = []
        """The recorded info keys the replay never returned (`BlockSink.info_not_returned`)."""

    def _kept(self, block: StepBlock) -> StepBlock:
        return block if self.obs else StepBlock({k: a for k, a in block.arrays.items() if not k.startswith("obs/")},
                                                block.rows)

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self._reset = self._kept(replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self._blocks.append(self._kept(replayed))

    def info_not_returned(self, keys: list[str]) -> None:
        self.info_unreturned = list(keys)

    def episode(self, meta: EpisodeMeta) -> Episode:
        """The replayed episode (a copy of `meta`; per-step fields empty when it has no step)."""
        assert self._reset is not None
        per_state = set(self._reset.arrays)
        template = self._blocks[0].arrays if self._blocks else {"actions": np.zeros((0, 0), np.float32)}
        names = dict.fromkeys([*template, *per_state])
        arrays = {n: np.concatenate(([self._reset[n]] if n in per_state else [])
                                    + [b[n] for b in self._blocks]) for n in names}
        if not self._blocks:
            arrays.update({n: np.zeros(0, bool) for n in FLAG_FIELDS}, rewards=np.zeros(0, np.float32))
        return Episode.from_fields(dataclasses.replace(meta), arrays)


class VerifySink(BlockSink):
    """Compares each replayed block with its recorded one as it comes (`simreel.verdicts.compare.BlockComparison`), and hands
    both on to `then` (the `-o` output, or a `Collected` replay) when given."""

    def __init__(self, tolerances: Tolerances, channels: list[ContactChannel], scope: CompareScope,
                 then: BlockSink | None) -> None:
        self._args = (tolerances, channels, scope)
        self.then = then
        self.explain = True
        """Whether a divergence is explained (`ReplayWorker._report`)."""
        self.start()

    def start(self) -> None:
        tolerances, channels, scope = self._args
        self.blocks = BlockComparison(tolerances, channels=channels, scope=scope)
        if self.then is not None:
            self.then.start()

    def reset(self, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.reset(recorded, replayed)
        if self.then is not None:
            self.then.reset(recorded, replayed)

    def steps(self, first: int, recorded: StepBlock, replayed: StepBlock) -> None:
        self.blocks.steps(recorded, replayed)
        if self.then is not None:
            self.then.steps(first, recorded, replayed)

    def info_not_returned(self, keys: list[str]) -> None:
        self.blocks.info_not_returned(keys)
        if self.then is not None:
            self.then.info_not_returned(keys)

    def comparison(self) -> EpisodeComparison:
        return self.blocks.comparison()
