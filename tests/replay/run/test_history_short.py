"""A late episode replayed after only the last step of the episode before it (from its recorded state, on a rebuilt
scene) instead of its whole history, kept where that is exact; else replayed again after its whole history, and its
report says why (`replay/run/workers.py`, the report's ``history`` entry)."""

from __future__ import annotations

import json

import pytest

from simreel.cli.main import main


def _record(path, task, shape, *, seeded=True, reconfigure_at=()):
    """`task` (env id, control mode), `shape` (episodes, steps): `episodes` episodes of `steps` random actions (torch's generator, seeded 1): reset with seed 100 + e (or only
    the first, `seeded` False: an RL rollout), rebuilding the scene at the episodes `reconfigure_at`."""
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    (env_id, control_mode), (episodes, steps) = task, shape
    rec = RecordWrapper(make_env(env_id, render_backend="none", control_mode=control_mode), path, overwrite=True,
                        contacts="none")
    torch.manual_seed(1)
    for e in range(episodes):
        options = {"reconfigure": True} if e in reconfigure_at else None
        rec.reset(seed=100 + e, options=options) if seeded or e == 0 else rec.reset(options=options)
        for _ in range(steps):
            rec.step(torch.rand(rec.action_space.shape) * 2 - 1)
    rec.close()
    return path


def _replayed(path, tmp_path, episodes: str, capsys) -> tuple[list[dict], str]:
    report = tmp_path / "report.json"
    code = main(["replay", str(path), "--episodes", episodes, "--report", str(report)])
    out, err = capsys.readouterr()
    assert code == 0, out + err
    return json.loads(report.read_text())["episodes"], out


@pytest.mark.parametrize(("env_id", "control_mode", "seeded"), [("PushCube-v1", "pd_joint_delta_pos", False),
                                                                 ("StackCube-v1", "pd_ee_delta_pose", True)])
def test_a_late_episode_replays_exact_after_only_the_last_step_before_it(tmp_path, capsys, env_id, control_mode,
                                                                          seeded):
    path = _record(tmp_path / "r.h5", (env_id, control_mode), (6, 10), seeded=seeded)
    (episode,), out = _replayed(path, tmp_path, "5", capsys)
    assert episode["verdict"] == "exact"
    assert episode["history"]["episodes"] == 1 and episode["history"]["steps"] == 1
    assert episode["history"]["why"].startswith("only the last step of episode 4, from its recorded state, on a "
                                                "scene just built, in place of its 5 predecessor(s)")
    assert "history: 1 predecessor episode(s), 1 step(s) replayed: only the last step of episode 4" in out


def test_the_last_step_comes_from_the_episodes_own_scene_chain(tmp_path, capsys):
    """Episode 3 rebuilt the scene: episode 5's history is episodes 3 and 4 (the last step of 4), and the episode
    after it (its scene's history again only that step) is kept only if exact, as it is."""
    path = _record(tmp_path / "r.h5", ("StackCube-v1", "pd_ee_delta_pose"), (7, 8), reconfigure_at=(3,))
    episodes, _ = _replayed(path, tmp_path, "5,6", capsys)
    assert [e["verdict"] for e in episodes] == ["exact", "exact"]
    assert "only the last step of episode 4" in episodes[0]["history"]["why"]
    assert "in place of its 2 predecessor(s)" in episodes[0]["history"]["why"]
    assert episodes[1]["history"] == {"episodes": 0, "steps": 0, "why": "its scene had just run its predecessors "
                                                                        "(replayed before it in this run)"}


def test_a_late_episode_not_exact_after_the_last_step_is_replayed_after_its_whole_history(tmp_path, capsys):
    """PickCube's episode 2 here leaves its recording at step 2 after episode 1's last step alone (PhysX keeps more
    of a scene's history than that step remakes): it is replayed again after episodes 0 and 1, exact, and its report
    says why."""
    path = _record(tmp_path / "r.h5", ("PickCube-v1", "pd_joint_pos"), (3, 30))
    (episode,), out = _replayed(path, tmp_path, "2", capsys)
    assert episode["verdict"] == "exact"
    assert episode["history"]["episodes"] == 2 and episode["history"]["steps"] == 60
    why = episode["history"]["why"]
    assert why.startswith("its whole history: replayed after only the last step of episode 1 (from its recorded "
                          "state), it was diverged (step 2: "), why
    assert "history: 2 predecessor episode(s), 60 step(s) replayed: its whole history" in out


def test_a_whole_run_replays_no_history(tmp_path, capsys):
    path = _record(tmp_path / "r.h5", ("PushCube-v1", "pd_joint_delta_pos"), (3, 5))
    episodes, out = _replayed(path, tmp_path, "0-2", capsys)
    assert [e["history"]["episodes"] for e in episodes] == [0, 0, 0]
    assert episodes[0]["history"]["why"] == "the first episode of its scene"
    assert "history:" not in out


@pytest.mark.parametrize(("task", "steps"), [(("PickCube-v1", "pd_joint_pos"), 60),
                                            (("PushCube-v1", "pd_joint_delta_pos"), 1)], ids=["fallback", "kept"])
def test_a_replay_written_with_o_holds_the_exact_replay_once(tmp_path, capsys, task, steps):
    """`-o`: the attempt after the last step alone is written aside (an output takes an episode index once); kept
    where exact, else dropped and the replay after the whole history is what the output holds."""
    from simreel.formats import open_reader

    path = _record(tmp_path / "r.h5", task, (3, 30))
    out, report = tmp_path / "out.h5", tmp_path / "report.json"
    assert main(["replay", str(path), "--episodes", "2", "-o", str(out), "--report", str(report), "-q"]) == 0, \
        capsys.readouterr()
    assert json.loads(report.read_text())["episodes"][0]["history"]["steps"] == steps
    with open_reader(out) as replayed, open_reader(path) as recorded:
        (meta,) = replayed.episodes
        assert meta.length == 30 and meta.verification.verdict == "exact"
        a, b = replayed.read_episode(meta.index), recorded.read_episode(2)
        assert all((a.env_states[k] == b.env_states[k]).all() for k in b.env_states)


SWEEP = [("PickCube-v1", "pd_joint_pos"), ("PickCube-v1", "pd_joint_delta_pos"), ("PushCube-v1", "pd_joint_delta_pos"),
         ("StackCube-v1", "pd_ee_delta_pose")]


@pytest.mark.slow
@pytest.mark.parametrize("seeded", [True, False], ids=["seeded", "unseeded"])
@pytest.mark.parametrize("task", SWEEP, ids=[f"{e}-{c}" for e, c in SWEEP])
def test_every_late_episode_replayed_alone_is_exact(tmp_path, task, seeded):
    """Eight 30-step episodes; each from the third on replayed alone, last first, in one worker (so each after only
    the last step of the one before it, or, where that is not exact, its whole history): all exact."""
    from simreel.formats import open_reader
    from simreel.model.components import Tolerances
    from simreel.replay.run.job import ReplayJob
    from simreel.replay.run.workers import ReplayWorker
    from simreel.replay.run.worklist import WorkItem, env_key

    path = _record(tmp_path / "r.h5", task, (8, 30), seeded=seeded)
    with open_reader(path) as reader:
        key = env_key(reader.meta)
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    try:
        reports = [worker.run(WorkItem(key, str(path), index)).report for index in range(7, 1, -1)]
    finally:
        worker.close()
    assert [r.verdict for r in reports] == ["exact"] * 6, [r.history for r in reports]
    assert all(r.history.steps == 1 or r.history.why.startswith("its whole history") for r in reports)
