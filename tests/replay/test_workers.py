"""Worker processes of `verify_recording(workers=N)` (`simreel.replay.workers`): user errors come back as
`SimreelError`s, never as a broken pool, and a session that fails to build leaves no file open."""

from __future__ import annotations

import dataclasses
import pickle

import pytest

from simreel.errors import EnvBuildError, RecordingFileError, SimreelError
from simreel.replay import workers


def test_recording_file_error_survives_pickling():
    e = pickle.loads(pickle.dumps(RecordingFileError("/data/run.h5", "no episode 7 (episodes: 0, 1)")))
    assert type(e) is RecordingFileError
    assert (e.path, e.problem, str(e)) == ("/data/run.h5", "no episode 7 (episodes: 0, 1)",
                                           "/data/run.h5: no episode 7 (episodes: 0, 1)")


def _job(path, **changes) -> workers.ReplayJob:
    from simreel.compare import Tolerances
    from simreel.replay.engine import ReplayerOptions

    job = workers.ReplayJob(path=str(path), mode="actions", resync=None, tolerances=Tolerances.for_mode("actions"),
                            replayer=ReplayerOptions(), keep_episode=False)
    return dataclasses.replace(job, **changes)


def test_a_worker_returns_user_errors_instead_of_raising(tmp_path, monkeypatch):
    """An initializer that raises breaks the whole pool; the error is kept and returned for each episode."""
    monkeypatch.setattr(workers, "_WORKER", None)
    workers._worker_init(_job(tmp_path / "missing.h5"))
    result = workers._worker_run(0)
    assert isinstance(result, RecordingFileError) and "missing.h5: no such file" in str(result)
    pickle.loads(pickle.dumps(result))  # it crosses the process boundary

    class FailingSession:
        def run(self, index):
            raise EnvBuildError(f"episode {index}: cannot build")

    monkeypatch.setattr(workers, "_WORKER", FailingSession())
    assert str(workers._worker_run(3)) == "episode 3: cannot build"


def test_the_parent_raises_what_a_worker_returned():
    with pytest.raises(EnvBuildError, match="cannot build"):
        workers._unwrap(EnvBuildError("cannot build"))


def test_a_session_that_cannot_build_its_env_closes_the_reader(record, monkeypatch):
    closed = []

    class Refused(SimreelError):
        pass

    def refuse(*args, **kwargs):
        raise Refused("the env does not build")

    real_open = workers.open_reader

    def spy(path):
        reader = real_open(path)
        real_close = reader.close

        def close():
            closed.append(path)
            real_close()

        reader.close = close
        return reader

    monkeypatch.setattr(workers, "open_reader", spy)
    monkeypatch.setattr(workers, "EpisodeReplayer", refuse)
    path = str(record("PickCube-v1", 2, 20))
    with pytest.raises(Refused):
        workers.ReplaySession(_job(path))
    assert closed == [path]
