"""Workers replaying for `-o` with a scratch folder (`ReplayJob.scratch`): a pool's worker process writes each
replayed episode to a scratch recording as it replays it and returns its path, never the episode's arrays; the
scratch recording holds the episode with its verdict; a replay that fails after some blocks leaves nothing."""

from __future__ import annotations

import io
import pickle
import shutil

import numpy as np
from support.damage import corrupt_chunk

from simreel.formats import open_reader
from simreel.model.components import Tolerances
from simreel.replay.run.job import ReplayJob
from simreel.replay.run.pool import run_pool
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import WorkItem, env_key


def _items(path) -> list[WorkItem]:
    with open_reader(path) as reader:
        return [WorkItem(env_key(reader.meta), str(path), m.index, m.length) for m in reader.episodes]


def _job(out, scratch, **changes) -> ReplayJob:
    return ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions"), output=str(out),
                     scratch=None if scratch is None else str(scratch), **changes)


def _array_shapes(result) -> list[tuple[int, ...]]:
    """Shapes of every numpy array pickling `result` sends from a worker process to the run."""
    shapes: list[tuple[int, ...]] = []

    class Pickler(pickle.Pickler):
        def reducer_override(self, obj):
            if isinstance(obj, np.ndarray):
                shapes.append(obj.shape)
            return NotImplemented

    Pickler(io.BytesIO()).dump(result)
    return shapes


def _pool_results(path, job) -> list:
    results = []
    worker = ReplayWorker(job)
    try:
        run_pool(worker, _items(path), 2, results.append)
    finally:
        worker.close()
    return results


def test_a_pool_worker_returns_the_path_of_a_scratch_recording_not_the_episode(record, tmp_path):
    path = record("PickCube-v1", 4, 20)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    results = _pool_results(path, _job(tmp_path / "out.h5", scratch))
    assert len({r.worker for r in results}) == 2  # this process and the pool's
    for r in results:
        assert r.error is None and r.episode is None
        assert r.scratch == scratch / f"episode_{r.item.index}.h5"
        assert not [s for s in _array_shapes(r) if s and s[0] >= r.item.steps]  # no per-step arrays
        with open_reader(r.scratch) as reader:
            (meta,) = reader.episodes
            assert meta.index == r.item.index and meta.length == 20
            assert meta.verification == r.report.verification()
            assert len(reader.read_episode(meta.index).actions) == 20

    whole = _pool_results(path, _job(tmp_path / "out.h5", None))  # no scratch folder (Ray): episodes come whole
    assert all(r.scratch is None and r.episode is not None for r in whole)
    assert all(any(s and s[0] == 21 for s in _array_shapes(r)) for r in whole)


def test_a_replay_that_fails_after_some_blocks_leaves_no_scratch_recording(record, tmp_path):
    path = tmp_path / "damaged.h5"
    shutil.copy(record("PickCube-v1", 2, 20), path)
    corrupt_chunk(path, "traj_0/actions", 3)  # steps 15-19: the third block of 7
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    worker = ReplayWorker(_job(tmp_path / "out.h5", scratch, block_rows=7))
    try:
        failed, ok = (worker.run(item) for item in _items(path))
        assert failed.error is not None and failed.scratch is None
        assert ok.error is None and ok.scratch == scratch / "episode_1.h5"
        assert sorted(p.name for p in scratch.iterdir()) == ["episode_1.h5", "episode_1.json"]
    finally:
        worker.close()
