"""Episodes recorded after an unseeded reset: remade bit for bit from the recorded generator states (RL rollouts
replay `exact`), and where their reset cannot be remade, replayed from the recorded initial state, which says so."""

from __future__ import annotations

import json

import pytest
from support.unseeded import record_unseeded, rl_rollout

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.replay import verify_recording

RL_PAIRS = [("PickCube-v1", "pd_joint_pos"), ("StackCube-v1", "pd_ee_delta_pose")]
SWEEP_PAIRS = [("PickCube-v1", "pd_joint_pos"), ("PickCube-v1", "pd_joint_delta_pos"),
               ("StackCube-v1", "pd_ee_delta_pose"), ("PushCube-v1", "pd_joint_pos"),
               ("PegInsertionSide-v1", "pd_joint_delta_pos"), ("PullCube-v1", "pd_ee_delta_pos"),
               ("LiftPegUpright-v1", "pd_joint_delta_pos"), ("PokeCube-v1", "pd_joint_pos")]


@pytest.mark.parametrize(("env_id", "control_mode"), RL_PAIRS)
def test_rl_rollout_replays_exact(tmp_path, env_id, control_mode):
    """One seeded reset then unseeded ones (each drawn from torch's generator, which the random actions advance
    too): every episode replays exact, its reset remade from the recorded generator states, not restored."""
    path = rl_rollout((env_id, control_mode), tmp_path / "rl.h5")
    with open_reader(path) as r:
        assert [m.seed is None for m in r.episodes] == [False, True, True]
        assert [sorted(m.reset_generators) for m in r.episodes] == [[], ["episode", "torch"], ["episode", "torch"]]
    report = verify_recording(path)
    assert [e.verdict for e in report.episodes] == ["exact"] * 3, [e.notes for e in report.episodes]
    assert not any("recorded initial state" in x for e in report.episodes for x in e.limits)


def test_an_unseeded_episode_alone_and_a_partial_reset_replay_exact(tmp_path, capsys):
    """Episode 2 replayed alone (after its predecessors, as every episode is), of a rollout whose unseeded resets are
    partial (``options={"env_idx": [0]}``), on PushCube: exact."""
    path = rl_rollout(("PushCube-v1", "pd_joint_delta_pos"), tmp_path / "p.h5", shape=(3, 10),
                      reset_options={"env_idx": [0]})
    code = main(["replay", str(path), "--episodes", "2", "--report", str(tmp_path / "r.json"), "-q"])
    (episode,) = json.loads((tmp_path / "r.json").read_text())["episodes"]
    assert code == 0, capsys.readouterr()
    assert episode["verdict"] == "exact", episode


def test_unseeded_episode_that_cannot_be_remade_replays_from_its_initial_state(tmp_path):
    """A wrapper below the recorder (`DrawsAtReset`) draws from the reset's generators before each reset, which a
    replay's reset does not: it cannot remake the episode, so the replay restores the recorded initial state and
    says why."""
    path = record_unseeded("SimreelLiftCube-v1", tmp_path / "u.h5", max_steps=10)
    (episode,) = verify_recording(path).episodes
    assert episode.verdict in ("exact", "within_tolerance", "diverged")
    assert any("did not remake the recorded initial state" in x for x in episode.limits), episode.limits
    assert "actions replayed from the recorded initial state" in episode.limits


@pytest.mark.slow
@pytest.mark.parametrize(("env_id", "control_mode"), SWEEP_PAIRS)
def test_rl_rollouts_of_many_tasks_replay_exact(tmp_path, env_id, control_mode):
    """Six 40-step episodes, one seeded then five unseeded, of each task/control-mode pair: all exact."""
    path = rl_rollout((env_id, control_mode), tmp_path / "rl.h5", shape=(6, 40))
    report = verify_recording(path)
    assert [e.verdict for e in report.episodes] == ["exact"] * 6, [e.notes for e in report.episodes]


def test_maniskill_vector_env_auto_resets_replay_exact(tmp_path):
    """`ManiSkillVectorEnv(auto_reset=True)` over a recorded one-env CPU env: its resets inside `step()` are
    unseeded resets of the env below it, which the recorder sees; every episode replays exact."""
    import torch
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    rec = RecordWrapper(make_env("PickCube-v1", render_backend="none", max_episode_steps=8), tmp_path / "v.h5",
                        contacts="none")
    vec = ManiSkillVectorEnv(rec, auto_reset=True, ignore_terminations=True)
    torch.manual_seed(0)
    vec.reset(seed=3)
    for _ in range(20):
        vec.step(torch.rand(1, 8) * 2 - 1)
    vec.close()
    report = verify_recording(tmp_path / "v.h5")
    assert [(e.index, e.verdict) for e in report.episodes] == [(0, "exact"), (1, "exact"), (2, "exact")]


@pytest.mark.parametrize("change", ["damaged", "written before"])
def test_damaged_or_absent_generator_states(tmp_path, change):
    """Damaged generator states are an `error` of that episode naming them, never replayed from others; a file
    written before simreel kept them replays its unseeded episode from the recorded initial state, as then."""
    import h5py

    from simreel.formats.hdf5.layout import EPISODE_ATTR

    path = rl_rollout(("PickCube-v1", "pd_joint_pos"), tmp_path / "d.h5", shape=(2, 5))
    with h5py.File(path, "a") as f:
        name = next(n for n in f if n.endswith("_1"))
        episode = json.loads(f[name].attrs[EPISODE_ATTR])
        if change == "damaged":
            episode["reset_generators"]["torch"] = "AAAA"
        else:
            del episode["reset_generators"]
        f[name].attrs[EPISODE_ATTR] = json.dumps(episode)
    report = verify_recording(path)
    first, second = report.episodes
    assert first.verdict == "exact"
    if change == "damaged":
        assert second.verdict == "error" and "reset_generators['torch'] does not decode" in second.error
    else:
        assert "actions replayed from the recorded initial state" in second.limits
