"""Replay workers (`simreel.replay.run.workers`): user errors come back in results (and cross process boundaries),
an env that does not build is not built again for its other episodes, and a worker keeps its env across the
recordings of one env key."""

from __future__ import annotations

import pickle

from simreel.errors import EnvBuildError, RecordingFileError
from simreel.formats import open_reader
from simreel.model.components import Tolerances
from simreel.replay.run.job import ReplayJob
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import WorkItem, env_key


def test_recording_file_error_survives_pickling():
    e = pickle.loads(pickle.dumps(RecordingFileError("/data/run.h5", "no episode 7 (episodes: 0, 1)")))
    assert type(e) is RecordingFileError
    assert (e.path, e.problem, str(e)) == ("/data/run.h5", "no episode 7 (episodes: 0, 1)",
                                           "/data/run.h5: no episode 7 (episodes: 0, 1)")


def _job(**changes) -> ReplayJob:
    return ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions"), **changes)


def _item(path, index: int = 0) -> WorkItem:
    with open_reader(path) as reader:
        return WorkItem(env_key(reader.meta), str(path), index, reader.episode_meta(index).length)


def test_a_worker_returns_user_errors_instead_of_raising(tmp_path):
    worker = ReplayWorker(_job())
    result = worker.run(WorkItem("key", str(tmp_path / "missing.h5"), 0))
    assert isinstance(result.error, RecordingFileError) and "missing.h5: no such file" in str(result.error)
    assert result.report is None and not result.env_error  # about the file's data, not its env
    again = pickle.loads(pickle.dumps(result))  # it crosses the process boundary
    assert str(again.error) == str(result.error)


def test_an_env_that_does_not_build_fails_each_of_its_episodes_without_being_built_again(record):
    path = record("PickCube-v1", 2, 10)
    worker = ReplayWorker(_job(imports=("simreel_no_such_module_xyz",)))
    try:
        first, second = worker.run(_item(path, 0)), worker.run(_item(path, 1))
    finally:
        worker.close()
    assert isinstance(first.error, EnvBuildError) and "simreel_no_such_module_xyz" in str(first.error)
    assert first.env_error
    assert second.error is first.error  # the remembered failure, not a second build


def test_a_worker_keeps_its_env_for_recordings_of_one_env_key_and_rebuilds_for_another(record):
    a, b = record("PickCube-v1", 2, 10), record("PickCube-v1", 1, 10, "--seed", "40")  # one time limit: one env key
    other = record("StackCube-v1", 1, 8)
    worker = ReplayWorker(_job())
    try:
        results = [worker.run(_item(a, 1))]
        env = worker._replayer.env
        results.append(worker.run(_item(b, 0)))
        assert worker._replayer.env is env
        results.append(worker.run(_item(other, 0)))
        assert worker._replayer.env is not env
        assert [r.report.verdict for r in results] == ["exact"] * 3, [r.error for r in results]
        assert [r.report.length for r in results] == [10, 10, 8]
        assert results[1].warnings == []  # the same machine: nothing differs
    finally:
        worker.close()
    assert len(worker._readers) == 0 and worker._replayer is None
