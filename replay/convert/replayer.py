"""`ConvertingReplayer`: the replay engine stepping converted actions — each recorded action turned into the target
control mode's by a converter (`simreel.replay.convert.control`), the episode replayed from its reproduced reset with
them, a block of steps at a time, for `simreel.replay.convert.convert` to check against the recording."""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np

from simreel.formats.base import EpisodeRows
from simreel.model.blocks import StepBlock
from simreel.replay.run.blocks import without_nan
from simreel.replay.run.engine import EpisodeReplayer, ReplayedEpisode
from simreel.replay.run.guards import task_code_errors
from simreel.replay.run.sinks import BlockSink

__all__ = ["ConvertingReplayer"]


class ConvertingReplayer(EpisodeReplayer):
    """An `EpisodeReplayer` that also replays converted actions (`replay_converted_rows`)."""

    def replay_converted_rows(self, source: EpisodeRows, converter: Any, sink: BlockSink, *,
                              rows: int | None = None) -> ReplayedEpisode:
        """Reproduce episode `source`'s reset, then step, for each recorded action, the action `converter` turns it
        into (`simreel.replay.convert.control`: bound to this env after the reset, called with each recorded action,
        returning the target mode's action and whether it was clipped), a block of `rows` recorded steps at a time
        (None: the reader's `block_rows`), each block handed to `sink` with its replay (which holds the converted
        actions). The result's notes say at which steps the target mode's limits clipped the action; its `commands`
        hold per step the tool-centre pose each action commanded (12 floats a step, kept whole)."""
        with task_code_errors():
            return self._replay_converted(source, converter, sink, rows=rows)

    def _replay_converted(self, source: EpisodeRows, converter: Any, sink: BlockSink, *,
                          rows: int | None) -> ReplayedEpisode:
        import torch

        start = time.perf_counter()
        done = self.reset_for(source.meta)
        self._check_converted_layout()
        recorded = source.reset()
        unseeded = self._start_unseeded(source, recorded)
        converter.bind(self.u)
        sink.start()
        sink.reset(recorded, self._reset_row(recorded))
        clipped: list[int] = []
        commands = np.full((source.length, 2, 7), np.nan)
        commanded = getattr(converter, "commanded", lambda: None)  # optional for converters of one's own
        self._stepped = self._stepped or source.length > 0
        shape = self.u.single_action_space.shape
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for first, block in source.blocks(rows):
                buf = self._block(block, np.zeros((block.rows, *shape), np.float32))
                for i, action in enumerate(without_nan(source, first, block["actions"])):
                    converted = converter(action)
                    buf.actions[i] = converted.action
                    clipped += [first + i] if converted.clipped else []
                    self._after_step(buf, i, self._step(torch.from_numpy(buf.actions[i]).to(self.u.device)))
                    _put(commands[first + i], getattr(converted, "wanted", None), commanded())
                sink.steps(first, block, buf.block())
        notes = [*done.notes, *source.meta.notes, *done.limits, *unseeded]
        if clipped:
            notes.append(f"the {converter.target_mode} action was clipped to its limits at {len(clipped)} step(s) "
                         f"(first: step {clipped[0]}): the recorded target was out of one step's reach; their commands "
                         "are not compared, the trajectory is")
        out = ReplayedEpisode(None, notes, limits=[*source.meta.notes, *done.limits, *unseeded], clipped=clipped,
                              commands=commands)
        out.compare_contacts = self._contacts is not None
        out.seconds = time.perf_counter() - start
        return out


    def _check_converted_layout(self) -> None:
        """The rebuilt env's state layout is the recording's, but for the state of a controller that keeps a target
        (the target control mode's, which the recorded one lacks)."""
        from simreel.sim.state import check_rebuilt_layout

        if not self._layout_checked and self.meta.state_layout:
            check_rebuilt_layout(self.u, self.meta.env_id, self.meta.state_layout, new_controller_state=True)
            self._layout_checked = True

    def _block(self, recorded: StepBlock, actions: np.ndarray | None = None) -> Any:
        """The engine's buffers, and the state of a controller the recorded control mode lacks (a target mode's
        target): the converted run's states hold it, as a recording in that mode does."""
        from simreel.sim.state import live_layout

        buf = super()._block(recorded, actions)
        if self.meta.state_layout and any(n.startswith("env_states/") for n in recorded.arrays):
            for key, spec in live_layout(self.u).items():
                if key not in self.meta.state_layout and key.startswith("controller/"):
                    buf.env_states[key] = np.zeros((buf.rows, *spec.shape), spec.dtype)
        return buf


def _put(rows: np.ndarray, *values: np.ndarray | None) -> None:
    for row, value in zip(rows, values, strict=True):
        if value is not None:
            row[:] = value
