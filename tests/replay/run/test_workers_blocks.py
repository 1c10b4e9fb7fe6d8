"""Replay workers read, replay, compare and write an episode a block of rows at a time (`ReplayJob.block_rows`):
the reports and the `-o` output are the same as when each episode is one block, for simreel's HDF5 and MCAP
recordings and ManiSkill's own files; a divergence in a later block is found at its step, and a corrupt chunk
in a later block makes the episode an error, never verified."""

from __future__ import annotations

import dataclasses
import shutil

import h5py
import numpy as np
import pytest
from support.damage import corrupt_chunk
from support.maniskill_files import record_maniskill

from simreel.cli.main import main
from simreel.errors import RecordingFileError
from simreel.formats import open_reader
from simreel.model.components import Tolerances
from simreel.replay.run.job import ReplayJob
from simreel.replay.run.output import ReplayedWriter, ReplayOutput
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import WorkItem, env_key

BLOCK = 7
"""Steps per block in these tests: episodes of 20 steps are read in blocks of 7, 7 and 6."""


def _job(mode: str = "actions", **changes) -> ReplayJob:
    resync = changes.pop("resync", None)
    tolerances = Tolerances.for_mode("resync" if resync else mode)
    return ReplayJob(mode=mode, resync=resync, tolerances=tolerances, **changes)


def _items(path) -> list[WorkItem]:
    with open_reader(path) as reader:
        return [WorkItem(env_key(reader.meta), str(path), m.index, m.length) for m in reader.episodes]


def _reports(path, job: ReplayJob) -> list[dict]:
    """Every episode's report (its timing left out), replayed by one worker with `job`."""
    worker = ReplayWorker(job)
    try:
        results = [worker.run(item) for item in _items(path)]
    finally:
        worker.close()
    assert all(r.error is None for r in results), [str(r.error) for r in results]
    out = []
    for r in results:
        d = dataclasses.asdict(r.report)
        d.pop("seconds")
        out.append(d)
    return out


def _to_mcap(src, tmp_path):
    dst = tmp_path / f"{src.stem}.mcap"
    assert main(["convert", str(src), str(dst), "-q"]) == 0
    return dst


@pytest.mark.parametrize(("mode", "resync"), [("actions", None), ("actions", 4), ("step", None), ("states", None)])
def test_every_mode_gives_the_same_report_in_blocks_as_whole(record, mode, resync):
    path = record("PickCube-v1", 2, 20)
    whole = _reports(path, _job(mode, resync=resync))
    assert _reports(path, _job(mode, resync=resync, block_rows=BLOCK)) == whole
    assert all(r["verdict"] in ("exact", "within_tolerance") for r in whole)


def test_an_mcap_recording_gives_the_same_report_in_blocks_as_whole(record, tmp_path):
    path = _to_mcap(record("PickCube-v1", 2, 20), tmp_path)
    whole = _reports(path, _job())
    assert _reports(path, _job(block_rows=BLOCK)) == whole
    assert [r["verdict"] for r in whole] == ["exact", "exact"]


def test_a_maniskill_file_gives_the_same_report_in_blocks_as_whole(tmp_path):
    path = record_maniskill(tmp_path, "PickCube-v1", episodes=2, steps=20, obs_mode="state")
    for mode in ("actions", "step"):
        whole = _reports(path, _job(mode))
        assert _reports(path, _job(mode, block_rows=BLOCK)) == whole
        assert [r["length"] for r in whole] == [20, 20]
    assert [r["verdict"] for r in whole] != ["error", "error"]


def test_a_divergence_in_the_third_block_is_found_at_its_step(record, tmp_path):
    path = tmp_path / "altered.h5"
    shutil.copy(record("PickCube-v1", 2, 20), path)
    with h5py.File(path, "r+") as f:
        f["traj_1/actions"][16] = -f["traj_1/actions"][16]  # step 16: the third block of 7 (steps 14-20)
    whole = _reports(path, _job())
    blocks = _reports(path, _job(block_rows=BLOCK))
    assert blocks == whole
    assert blocks[0]["verdict"] == "exact"
    first = blocks[1]["first_divergence"]
    assert blocks[1]["verdict"] == "diverged" and first["step"] == 16 and first["at"] == "step"
    assert blocks[1]["explanation"] is not None


def test_a_corrupt_chunk_in_a_later_block_makes_the_episode_an_error(record, tmp_path):
    path = tmp_path / "damaged.h5"
    shutil.copy(record("PickCube-v1", 2, 20), path)
    corrupt_chunk(path, "traj_0/actions", 3)  # steps 15-19: the third block of 7
    with open_reader(path) as reader:  # the blocks before it read, the one holding the chunk does not
        rows = reader.open_episode(0)
        blocks = rows.blocks(BLOCK)
        assert [next(blocks)[0], next(blocks)[0]] == [0, 7]
        with pytest.raises(RecordingFileError, match="traj_0/actions is corrupt: its data fails its checksum"):
            next(blocks)
    worker = ReplayWorker(_job(block_rows=BLOCK))
    try:
        results = [worker.run(item) for item in _items(path)]
    finally:
        worker.close()
    assert results[0].report is None and isinstance(results[0].error, RecordingFileError)
    assert "traj_0/actions is corrupt" in str(results[0].error)
    assert results[1].report.verdict == "exact"


def _replay_to(path, out, *, block_rows: int | None, stream: bool, mode: str = "actions"):
    """Replay every episode of `path` into `out` (-o): streamed block by block by the worker, or returned whole."""
    with open_reader(path) as reader:
        meta, order = reader.meta, [m.index for m in reader.episodes]
    writer = ReplayedWriter(ReplayOutput(str(out)), meta, order)
    worker = ReplayWorker(_job(mode, output=str(out), block_rows=block_rows))
    worker.output = writer if stream else None
    try:
        for item in _items(path):
            result = worker.run(item)
            assert result.error is None, result.error
            assert (result.episode is None) == stream
            writer.put(item.index, result.episode)
    finally:
        worker.close()
        writer.close()


@pytest.mark.parametrize("mode", ["actions", "states"])
def test_output_written_block_by_block_equals_the_output_written_whole(record, tmp_path, mode):
    path = record("PickCube-v1", 2, 20)
    _replay_to(path, tmp_path / "whole.h5", block_rows=None, stream=False, mode=mode)
    _replay_to(path, tmp_path / "blocks.h5", block_rows=BLOCK, stream=True, mode=mode)
    with open_reader(tmp_path / "whole.h5") as whole, open_reader(tmp_path / "blocks.h5") as blocks:
        assert [m.to_json() for m in blocks.episodes] == [m.to_json() for m in whole.episodes]
        assert blocks.meta.obs_layout == whole.meta.obs_layout
        assert blocks.meta.contact_channels == whole.meta.contact_channels
        for m in whole.episodes:
            a, b = whole.read_episode(m.index).fields(), blocks.read_episode(m.index).fields()
            assert list(a) == list(b)
            for name in a:
                np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        assert whole.episodes[0].verification.verdict in ("exact", "within_tolerance")
