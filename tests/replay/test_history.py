"""An episode's scene history (`simreel.replay.history`): the rule on hand-made episode lists, and real actions
replays that give the recorded numbers bit for bit only after it. The recording: SimreelLiftCube-v1's scripted
grasp and lift from seed 3, three episodes; its episode 2 replayed on a fresh env leaves the recording at step 9
(cube angular velocity off by 3 rad/s), replayed after episodes 0 and 1 it is exact."""

from __future__ import annotations

import shutil

import pytest
from support.damage import corrupt_chunk

from simreel.cli.main import main
from simreel.compare import Tolerances
from simreel.episode import EpisodeMeta
from simreel.formats import open_reader
from simreel.replay.history import scene_history
from simreel.replay.workers import ReplayJob, ReplayWorker
from simreel.replay.worklist import WorkItem, env_key


def _indices(episodes: list[EpisodeMeta], index: int) -> list[int]:
    return [ep.index for ep in scene_history(episodes, index)]


def test_the_history_runs_back_to_the_first_episode_of_its_sub_scene():
    episodes = [EpisodeMeta(i) for i in range(4)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], [0, 1], [0, 1, 2]]


def test_a_reset_that_rebuilt_the_scene_starts_a_new_history():
    episodes = [EpisodeMeta(0), EpisodeMeta(1), EpisodeMeta(2, reconfigured=True, seed=2), EpisodeMeta(3),
                EpisodeMeta(4)]
    assert _indices(episodes, 2) == []  # its own reset rebuilt the scene
    assert _indices(episodes, 4) == [2, 3]  # the rebuilding episode starts the chain
    assert _indices(episodes, 1) == [0]


def test_only_episodes_of_the_same_sub_scene_count():
    episodes = [EpisodeMeta(0, env_idx=0), EpisodeMeta(1, env_idx=1), EpisodeMeta(2, env_idx=0),
                EpisodeMeta(3, env_idx=1, reconfigured=True), EpisodeMeta(4, env_idx=1)]
    assert _indices(episodes, 2) == [0]
    assert _indices(episodes, 1) == []  # the first of sub-scene 1: the recorder's env was fresh
    assert _indices(episodes, 4) == [3]


def test_an_unknown_rebuild_is_taken_as_none():
    episodes = [EpisodeMeta(0, reconfigured=None), EpisodeMeta(1, reconfigured=None), EpisodeMeta(2, reconfigured=None)]
    assert _indices(episodes, 2) == [0, 1]  # one predecessor too many costs time, one too few a wrong verdict


@pytest.fixture(scope="module")
def lift(record):
    """SimreelLiftCube-v1, scripted, seeds 3 to 5: episode 2 is exact only after its predecessors."""
    return record("SimreelLiftCube-v1", 3, 60)


def _replay(*args) -> int:
    return main(["replay", *map(str, args), "-q"])


def test_an_episode_replayed_alone_is_replayed_after_its_history(lift, tmp_path, capsys):
    report = tmp_path / "report.json"
    assert _replay(lift, "--episodes", "2", "--report", report) == 0  # was: diverged at step 9
    assert "1 exact" in capsys.readouterr().out
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    try:
        with open_reader(lift) as reader:
            key = env_key(reader.meta)
        result = worker.run(WorkItem(key, str(lift), 2))
        assert result.report.verdict == "exact" and result.history == [0, 1]
        assert "episode 2 replayed after its recorded predecessor(s) 0–1 (PhysX results depend on the scene's " \
               "history); 0–1 replayed for that, not verified" in result.report.notes
        assert worker.run(WorkItem(key, str(lift), 0)).history == []  # the scene is rebuilt: it ran 0, 1, 2
        assert worker.run(WorkItem(key, str(lift), 2)).history == [1]  # it ran episode 0 already
    finally:
        worker.close()


def test_an_episode_whose_history_cannot_be_read_says_so(lift, tmp_path):
    damaged = tmp_path / "damaged.h5"
    shutil.copy(lift, damaged)
    corrupt_chunk(damaged, "traj_0/actions", 1)
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    try:
        with open_reader(damaged) as reader:
            result = worker.run(WorkItem(env_key(reader.meta), str(damaged), 1))
    finally:
        worker.close()
    assert result.error is None and result.history == []  # replayed on a rebuilt scene, without its history
    assert any("replayed without the episodes that ran before it in the recorder's scene: episode 0 cannot be read"
               in limit for limit in result.report.limits)


def test_episodes_asked_in_reverse_order_are_exact(lift, capsys):
    assert _replay(lift, "--episodes", "2,1,0") == 0
    assert "3 exact" in capsys.readouterr().out


def test_two_workers_are_exact(lift, capsys):
    assert _replay(lift, "--workers", "2") == 0  # the pool takes episodes 0 and 1, this process episode 2
    assert "3 exact" in capsys.readouterr().out


def test_one_env_replaying_two_files_gives_each_its_own_history(record, tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    for name in ("a.h5", "b.h5"):  # seeds 4 and 5: b.h5's episode 1 left its recording after a.h5's episodes
        shutil.copy(record("SimreelLiftCube-v1", 2, 60, "--seed", "4"), data / name)
    assert _replay(data) == 0  # one env key: one env replays a.h5, then b.h5
    assert "4 exact" in capsys.readouterr().out
