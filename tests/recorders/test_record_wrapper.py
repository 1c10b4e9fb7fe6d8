"""RecordWrapper writes exactly what the env reported, for real ManiSkill tasks."""

from __future__ import annotations

import os
import re
import shutil
import signal

import gymnasium as gym
import numpy as np
import pytest
import torch

from simreel.errors import StateLayoutError, UsageError
from simreel.formats import open_reader
from simreel.model.state_tree import flatten, to_numpy
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env

TASKS = [
    ("PickCube-v1", {}),
    ("StackCube-v1", {}),
    ("PegInsertionSide-v1", {}),  # merged views: registry holds peg / box_with_hole, not peg_0
    ("RotateValveLevel0-v1", {}),  # articulation with its own DOF
]


def _run(env, steps, seed, rng):
    """Step with random actions, keeping what the env itself reported at each step."""
    obs, _ = env.reset(seed=seed)
    u = env.unwrapped
    seen = {"states": [flatten(u.get_state_dict())], "rewards": [], "terminated": [], "truncated": [], "info": []}
    for _ in range(steps):
        action = rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32)
        _, r, te, tr, info = env.step(action)
        seen["states"].append(flatten(u.get_state_dict()))
        seen["rewards"].append(float(to_numpy(r)[0]))
        seen["terminated"].append(bool(to_numpy(te)[0]))
        seen["truncated"].append(bool(to_numpy(tr)[0]))
        seen["info"].append({k: to_numpy(v).reshape(-1)[0] for k, v in info.items() if k != "reconfigure"})
    return seen


@pytest.mark.parametrize("env_id,kwargs", TASKS, ids=[t[0] for t in TASKS])
def test_recording_reads_back_what_the_env_reported(tmp_path, env_id, kwargs):
    path = tmp_path / "rec.h5"
    env = RecordWrapper(make_env(env_id, **kwargs), path)
    rng = np.random.default_rng(0)
    truth = [_run(env, 12, seed, rng) for seed in (5, 6)]
    # Stock tasks on the CPU sim are read by the fast path; this test proves it exact at every step.
    assert env._capture.fast is not None
    env.close()

    with open_reader(path) as r:
        assert [m.seed for m in r.episodes] == [5, 6]
        assert r.meta.env_id == env_id
        assert r.meta.versions["mani_skill"] == "3.0.1"
        reg = r.meta.scene
        for m, seen in zip(r.episodes, truth, strict=True):
            ep = r.read_episode(m.index)
            ep.check_shapes()
            assert ep.length == m.length == 12
            assert set(ep.env_states) == set(seen["states"][0]) == set(r.meta.state_layout)
            for t, state in enumerate(seen["states"]):
                for key, value in state.items():
                    np.testing.assert_array_equal(ep.env_states[key][t], value[0], err_msg=f"{key} t={t}")
            np.testing.assert_array_equal(ep.rewards, np.float32(seen["rewards"]))
            np.testing.assert_array_equal(ep.terminated, seen["terminated"])
            np.testing.assert_array_equal(ep.truncated, seen["truncated"])
            for key in r.meta.info_layout:
                np.testing.assert_array_equal(ep.info[key], [i[key] for i in seen["info"]], err_msg=key)
            if "success" in seen["info"][0]:
                np.testing.assert_array_equal(ep.success, [bool(i["success"]) for i in seen["info"]])
    if env_id == "PegInsertionSide-v1":
        assert {"peg", "box_with_hole"} <= set(reg["actors"])
        assert reg["actors"]["peg"]["merged"] and "peg_0" not in reg["actors"]
        assert "actors/peg" in r.meta.state_layout


def test_contact_channels_match_maniskill_queries(tmp_path):
    """Net and pairwise forces equal ManiSkill's own per-body queries at every step."""
    env = RecordWrapper(make_env("PickCube-v1"), tmp_path / "c.h5", contacts="auto")
    u = env.unwrapped
    names = [c.name for c in env.meta.contact_channels]
    assert "cube" in names and "panda/panda_leftfinger:cube" in names
    cube = u.scene.actors["cube"]
    finger = u.agent.robot.links_map["panda_leftfinger"]
    env.reset(seed=1)
    expected_net, expected_pair = [], []
    # Close the gripper on the cube's neighbourhood by random actions; at least the table contact is non-zero.
    rng = np.random.default_rng(1)
    for _ in range(15):
        env.step(rng.uniform(-1, 1, size=env.action_space.shape).astype(np.float32))
        expected_net.append(to_numpy(cube.get_net_contact_forces())[0])
        expected_pair.append(to_numpy(u.scene.get_pairwise_contact_forces(finger, cube))[0])
    env.close()
    with open_reader(tmp_path / "c.h5") as r:
        ep = r.read_episode(0)
    got_net = ep.contact_forces[:, names.index("cube")]
    got_pair = ep.contact_forces[:, names.index("panda/panda_leftfinger:cube")]
    np.testing.assert_allclose(got_net, expected_net, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got_pair, expected_pair, rtol=1e-5, atol=1e-5)
    # The cube rests on the table: its net force is its weight, upwards (m·g = 0.6278 N).
    assert got_net[0, 2] == pytest.approx(0.6278, abs=0.01)


def test_long_episode_streams_in_blocks(tmp_path, monkeypatch):
    """An episode longer than the block and the in-memory limit streams to a scratch file and reads back whole."""
    import simreel.formats.hdf5.writer as hdf5

    monkeypatch.setattr(hdf5, "_SPILL_BYTES", 4096)  # in this process: the writer must write here to see it
    env = RecordWrapper(make_env("PickCube-v1", max_episode_steps=300), tmp_path / "long.h5", block_steps=16,
                        contacts="none", writer_process=False)
    env.reset(seed=0)
    states = []
    for _ in range(70):
        env.step(np.zeros(env.action_space.shape, np.float32))
        assert env._buffer.rows <= 16
        states.append(to_numpy(env.unwrapped.get_state_dict()["actors"]["cube"])[0])
    assert (hdf5.partial_dir(tmp_path / "long.h5") / "traj_0.h5").exists()  # spilled, not held in memory
    env.close()
    assert not hdf5.partial_dir(tmp_path / "long.h5").exists()
    with open_reader(tmp_path / "long.h5") as r:
        ep = r.read_episode(0)
    assert ep.length == 70 and ep.contact_forces is None
    np.testing.assert_array_equal(ep.env_states["actors/cube"][1:], states)


def test_reset_without_steps_leaves_no_episode_and_step_before_reset_or_after_close_is_refused(tmp_path):
    from simreel.errors import UsageError

    env = RecordWrapper(make_env("PushCube-v1"), tmp_path / "e.h5")
    with pytest.raises(UsageError, match="before reset"):
        env.step(np.zeros(env.action_space.shape, np.float32))
    env.reset(seed=0)
    env.reset(seed=1)
    env.step(np.zeros(env.action_space.shape, np.float32))
    env.close()
    with open_reader(tmp_path / "e.h5") as r:
        assert [(m.index, m.seed, m.length) for m in r.episodes] == [(1, 1, 1)]
    for late in (lambda: env.step(np.zeros(env.action_space.shape, np.float32)), lambda: env.reset(seed=2)):
        with pytest.raises(UsageError, match=r"RecordWrapper\.(step|reset)\(\) after close\(\): the recording is closed"):
            late()


def test_each_episode_notes_its_place_in_the_scene_that_ran_it(tmp_path):
    """`EpisodeMeta.chain`: an episode of no step (discarded) ran nothing; a reconfiguring reset starts a chain."""
    env = RecordWrapper(make_env("PushCube-v1"), tmp_path / "e.h5")
    zero = np.zeros(env.action_space.shape, np.float32)
    for seed, options, steps in ((0, None, 0), (1, None, 1), (2, None, 1), (3, {"reconfigure": True}, 0), (4, None, 1),
                                 (5, {"reconfigure": True}, 1), (6, None, 1)):
        env.reset(seed=seed, options=options)
        for _ in range(steps):
            env.step(zero)
    env.close()
    with open_reader(tmp_path / "e.h5") as r:
        assert [(m.index, m.chain.start, m.chain.position) for m in r.episodes] == \
            [(1, 1, 0), (2, 1, 1), (4, 4, 0), (5, 5, 0), (6, 5, 1)]


def test_observations_and_poses_when_asked(tmp_path):
    env = RecordWrapper(make_env("PickCube-v1"), tmp_path / "o.h5", record_obs=True, poses=True)
    obs, _ = env.reset(seed=2)
    first_obs = to_numpy(obs)[0]
    for _ in range(3):
        obs, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
    env.close()
    with open_reader(tmp_path / "o.h5") as r:
        ep = r.read_episode(0)
        bodies = r.meta.pose_bodies
    np.testing.assert_array_equal(ep.obs["state"][0], first_obs)
    np.testing.assert_array_equal(ep.obs["state"][-1], to_numpy(obs)[0])
    # An actor's recorded world pose is the pose in its state row (first 7 floats).
    cube = bodies.index("cube")
    np.testing.assert_array_equal(ep.body_poses[:, cube], ep.env_states["actors/cube"][:, :7])
    assert "panda/panda_hand" in bodies


def test_declared_custom_state_is_recorded_through_the_fast_reader(tmp_path):
    """A task with CustomStateMixin state is read fast too, and its custom key is recorded exactly."""
    env = RecordWrapper(make_env("SimreelLiftCube-v1"), tmp_path / "c.h5")
    env.reset(seed=0)
    heights = [float(env.unwrapped.goal_height[0])]
    for _ in range(3):
        env.step(np.zeros(env.action_space.shape, np.float32))
        heights.append(float(env.unwrapped.goal_height[0]))
    assert env._capture.fast is not None
    env.close()
    with open_reader(tmp_path / "c.h5") as r:
        np.testing.assert_array_equal(r.read_episode(0).env_states["goal_height"], np.float32(heights))


def test_state_layout_change_is_refused(tmp_path):
    env = RecordWrapper(make_env("PickCube-v1"), tmp_path / "l.h5")
    env.meta.state_layout = dict(env.meta.state_layout)
    env.meta.state_layout.pop("actors/cube")
    with pytest.raises(StateLayoutError, match="actors/cube"):
        env.reset(seed=0)
    env.close()


RENAMED_LINK_TASK = """
import sapien, torch
from mani_skill.envs.tasks.tabletop.push_cube import PushCubeEnv
from mani_skill.utils.registration import register_env

@register_env("SimreelTestRenamedLink-v1", max_episode_steps=20)
class RenamedLink(PushCubeEnv):
    \"\"\"A slider whose moving link is named after the episode's seed: the state layout stays, the bodies do not.\"\"\"
    def __init__(self, *args, **kwargs):
        super().__init__(*args, reconfiguration_freq=1, **kwargs)

    def _load_scene(self, options):
        super()._load_scene(options)
        seed = int(self._batched_episode_rng[0].randint(0, 2))
        builder = self.scene.create_articulation_builder()
        base = builder.create_link_builder()
        base.set_name("base")
        base.add_box_collision(half_size=[0.02, 0.02, 0.02])
        moving = builder.create_link_builder(base)
        moving.set_name(("drawer", "knob")[seed])
        moving.add_box_collision(half_size=[0.02, 0.02, 0.02])
        moving.set_joint_properties("prismatic", limits=[[0, 0.1]], pose_in_parent=sapien.Pose(),
                                    pose_in_child=sapien.Pose(), friction=0, damping=0)
        builder.initial_pose = sapien.Pose(p=[0.3, 0.3, 0.02])
        self.slider = builder.build(name="slider", fix_root_link=True)
"""


def test_a_rebuilt_scene_without_a_body_the_contact_channels_name_is_one_clear_error(tmp_path):
    """Contact channels are chosen from the first scene; a later scene that lacks one of their bodies (a link named
    per episode, the state layout the same) ended `record` with `internal error: KeyError` (exit 3)."""
    from simreel.sim.user_code import import_user_code

    task = tmp_path / "renamed_link_task.py"
    task.write_text(RENAMED_LINK_TASK)
    import_user_code(str(task))
    env = RecordWrapper(make_env("SimreelTestRenamedLink-v1"), tmp_path / "c.h5")
    moving = next(b for ch in env.meta.contact_channels for b in ch.bodies if b.startswith("slider/") and b != "slider/base")
    with pytest.raises(StateLayoutError, match=f"this episode's scene has no body '{moving}', which the recording's "
                                               "contact channels name .*record without contacts"):
        for seed in range(20):
            env.reset(seed=seed)
    env.close()


def test_unseeded_reset_records_no_seed_and_seeded_one_its_seed(tmp_path):
    """ManiSkill keeps a stale _episode_seed after reset(seed=None): the file must not claim it."""
    env = RecordWrapper(make_env("PushCube-v1"), tmp_path / "s.h5")
    for seed in (5, None):
        env.reset(seed=seed)
        env.step(np.zeros(env.action_space.shape, np.float32))
    env.close()
    with open_reader(tmp_path / "s.h5") as r:
        assert [m.seed for m in r.episodes] == [5, None]


@pytest.mark.filterwarnings("ignore:the matrix subclass:PendingDeprecationWarning")
def test_every_kind_of_action_is_checked_and_recorded_as_given(tmp_path):
    """Actions in each form ManiSkill takes: recorded as given (as float32); an action holding NaN or infinity is
    refused before the env steps, whatever its dtype, and so is one beyond float32's range; so is a tensor ManiSkill
    would fail on (one that requires grad, of an unsigned dtype torch cannot clamp, on the meta device); so
    is one of another shape, type or dtype (a list, which ManiSkill would refuse with a TypeError; bfloat16)."""
    from simreel.errors import ActionError

    env = RecordWrapper(make_env("PickCube-v1"), tmp_path / "a.h5", contacts="none", writer_process=False)
    env.reset(seed=0)
    given = [np.full(8, 0.5, np.float32), np.full((1, 8), -0.25), np.ones(8, np.int64), np.zeros(8, bool),
             np.array([1e38, 1e38, 0, 0, 0, 0, 0, 0]), torch.full((1, 8), 0.75), np.asmatrix(np.full(8, 0.375))]
    for action in given:
        env.step(action)
    for huge in (np.full(8, 1.7e308), np.array([0, 0, 0, -1e39, 0, 0, 0, 0])):
        with pytest.raises(ActionError, match="beyond float32's range .*, which the recording cannot hold"):
            env._actions(huge)  # finite (the first even where their sum is not), but no float32 holds them
    for tensor, said in ((torch.zeros(8, requires_grad=True), "requires grad"),
                         (torch.zeros(8, dtype=torch.uint64), "dtype torch.uint64"),
                         (torch.zeros(8, device="meta"), "meta device")):
        with pytest.raises(ActionError, match=said):
            env.step(tensor)  # each would fail inside ManiSkill's step
    for bad in (np.float32, np.float64):
        for value in (np.nan, np.inf, -np.inf):
            action = np.zeros(8, bad)
            action[3] = value
            with pytest.raises(ActionError, match="NaN or infinity"):
                env.step(action)
    for wrong in (np.zeros(7, np.float32), np.zeros((2, 8), np.float32), np.zeros(8, np.complex64), [0.0] * 8,
                  torch.zeros(8, dtype=torch.bfloat16)):
        with pytest.raises(ActionError, match="an action of"):
            env.step(wrong)
    env.close()
    with open_reader(tmp_path / "a.h5") as r:
        recorded = r.read_episode(0).actions
    expected = np.stack([np.asarray(to_numpy(a), np.float64).reshape(8) for a in given]).astype(np.float32)
    np.testing.assert_array_equal(recorded, expected)


def _episodes_read_whole(path) -> list[tuple[int, int]]:
    """(index, length) of each episode in `path`, each read whole (a length its rows do not have fails the read)."""
    with open_reader(path) as r:
        return [(m.index, len(r.read_episode(m.index).actions)) for m in r.episodes]


@pytest.mark.parametrize("writer_process", [True, False], ids=["writer process", "in-process"])
def test_a_ctrl_c_right_after_a_step_is_stored_keeps_the_episode_whole(tmp_path, monkeypatch, writer_process):
    """A real SIGINT once the step's rows are in the buffer: the episode committed by close (as the CLI's cleanup
    does) holds that step, and says so."""
    from simreel.recorders.step_buffer import StepBuffer

    rec = RecordWrapper(make_env("PickCube-v1"), tmp_path / "r.h5", writer_process=writer_process)
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    for _ in range(5):
        rec.step(zero)
    push = StepBuffer.push

    def push_then_ctrl_c(self, *args):
        push(self, *args)
        os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(StepBuffer, "push", push_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        rec.step(zero)
    monkeypatch.undo()
    rec.close()
    assert [(m.index, m.length) for m in rec.episodes_committed] == [(0, 6)]
    assert _episodes_read_whole(tmp_path / "r.h5") == [(0, 6)]


def test_a_ctrl_c_while_an_ended_episode_is_handed_over_loses_none_of_it(tmp_path, monkeypatch):
    """A real SIGINT while the reset hands the ended episode's steps to the writer process (as its send first reads
    what the child has said): the steps and the commit still go out; the Ctrl-C comes after."""
    from simreel.recorders.writer_process import ProcessWriter

    rec = RecordWrapper(make_env("PickCube-v1"), tmp_path / "r.h5")
    rec.reset(seed=0)
    for _ in range(10):
        rec.step(np.zeros(rec.action_space.shape, np.float32))
    news_waiting, armed = ProcessWriter._news_waiting, [True]

    def ctrl_c_in_first_look(self, seconds=0):
        if armed and seconds == 0:
            armed.clear()
            os.kill(os.getpid(), signal.SIGINT)
        return news_waiting(self, seconds)

    monkeypatch.setattr(ProcessWriter, "_news_waiting", ctrl_c_in_first_look)
    with pytest.raises(KeyboardInterrupt):
        rec.reset(seed=1)
    monkeypatch.undo()
    assert not armed
    rec.close()
    assert [(m.index, m.length) for m in rec.episodes_committed] == [(0, 10)]
    assert _episodes_read_whole(tmp_path / "r.h5") == [(0, 10)]


def test_a_partial_reset_naming_an_env_twice_or_none_there_is_refused_before_anything_changes(tmp_path):
    """env_idx [0, 0] would begin two episodes for env 0 at once (one never ended); [3] names no env: both are
    refused, and the recording goes on as if they had not been asked."""
    rec = RecordWrapper(make_env("PickCube-v1"), tmp_path / "r.h5")
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    rec.step(zero)
    for env_idx in ([0, 0], [3], [-1], []):  # []: ManiSkill would fail half way through the reset
        with pytest.raises(UsageError, match="name each env to reset once, from 0 to 0"):
            rec.reset(seed=1, options={"env_idx": env_idx})
    with pytest.raises(UsageError, match="holds bool values; give the indices of the envs to reset, from 0 to 0"):
        rec.reset(seed=1, options={"env_idx": np.array([True])})
    rec.step(zero)
    rec.reset(seed=1, options={"env_idx": [0]})
    rec.step(zero)
    rec.close()
    assert [(m.index, m.length) for m in rec.episodes_committed] == [(0, 2), (1, 1)]
    assert _episodes_read_whole(tmp_path / "r.h5") == [(0, 2), (1, 1)]


def test_wrappers_that_change_actions_must_sit_above_the_recorder(tmp_path):
    import gymnasium as gym

    from simreel.errors import UsageError

    with pytest.raises(UsageError, match="RecordWrapper wraps ClipAction, which changes the task's actions"):
        RecordWrapper(gym.wrappers.ClipAction(make_env("PushCube-v1")), tmp_path / "w.h5")
    assert not (tmp_path / "w.h5").exists()


def test_an_autoreset_below_the_recorder_is_refused(tmp_path):
    """Autoreset starts the next episode inside step(): below the recorder, two episodes were written as one (a
    replay then diverged with cause `undetermined`)."""
    import gymnasium as gym

    with pytest.raises(UsageError, match="RecordWrapper wraps Autoreset, .* Put Autoreset above RecordWrapper"):
        RecordWrapper(gym.wrappers.Autoreset(make_env("PushCube-v1")), tmp_path / "w.h5")
    assert not (tmp_path / "w.h5").exists()


def test_an_exception_that_leaves_a_with_block_stops_the_recording_as_record_does(tmp_path):
    """`with RecordWrapper(..., overwrite=True) as env:` left by an exception closed the recording as if complete:
    the old file was replaced by the fragment, without a note. Now it stops: the old file stays, the new recording
    waits in its side folder with the running episode noted as cut short."""
    out, zero = tmp_path / "r.h5", np.zeros(8, np.float32)
    with RecordWrapper(make_env("PickCube-v1"), out) as rec:
        rec.reset(seed=0)
        rec.step(zero)
    old = out.read_bytes()
    with pytest.raises(RuntimeError, match="the training loop failed"):
        with RecordWrapper(make_env("PickCube-v1"), out, overwrite=True) as rec:
            rec.reset(seed=1)
            for _ in range(3):
                rec.step(zero)
            raise RuntimeError("the training loop failed")
    assert out.read_bytes() == old
    with open_reader(tmp_path / "r.h5.partial" / "r.h5") as r:
        assert [(m.seed, m.length, m.notes) for m in r.episodes] == [
            (1, 3, ["cut short: an error (RuntimeError) stopped the recording before this episode ended"])]


def test_the_wrapper_keeps_its_arguments_in_env_spec(tmp_path):
    """Like gymnasium's own wrappers (RecordConstructorArgs): the spec names the recorder and its options."""
    path = tmp_path / "r.h5"
    env = RecordWrapper(make_env("PushCube-v1"), path, contacts="none", record_obs=True, block_steps=16)
    try:
        wrapper = env.spec.additional_wrappers[-1]
        assert wrapper.name == "RecordWrapper"
        assert wrapper.kwargs == {"path": str(path), "contacts": "none", "record_obs": True, "block_steps": 16}
        assert env.options.record_obs and env.options.block_steps == 16
    finally:
        env.close()


def test_the_scene_fingerprint_is_kept_once_and_per_rebuilt_scene(record):
    """The recording keeps the fingerprint of the scene the recorder found; an episode whose reset rebuilt the scene
    keeps what differs in its own (a heterogeneous task's cabinet), which is that scene's fingerprint."""
    from simreel.sim.fingerprint import apply_changes, scene_fingerprint
    from simreel.sim.rebuild import reset_to_episode

    with open_reader(record("PickCube-v1", 2, 5)) as r:
        meta, episodes = r.meta, r.episodes
    env = make_env("PickCube-v1", render_backend="none")
    try:
        assert meta.scene_fingerprint == scene_fingerprint(env.unwrapped)
    finally:
        env.close()
    assert meta.scene_fingerprint["bodies"]["cube"]["mass"] > 0
    assert all(m.scene_changes == {} for m in episodes)  # the same scene all along

    with open_reader(record("SimreelHeteroDrawer-v1", 2, 5)) as r:
        meta, episodes = r.meta, r.episodes
    assert all(m.reconfigured and set(m.scene_changes) == {"bodies"} for m in episodes)
    assert all(name.startswith("cabinet") for m in episodes for name in m.scene_changes["bodies"])
    env = make_env("SimreelHeteroDrawer-v1", render_backend="none")
    try:
        for m in episodes:
            reset_to_episode(env, m, scene_seed=None)
            assert apply_changes(meta.scene_fingerprint, m.scene_changes) == scene_fingerprint(env.unwrapped)
    finally:
        env.close()


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
@pytest.mark.parametrize("writer_process", [True, False], ids=["writer process", "in-process"])
def test_stop_keeps_the_old_file_and_notes_only_the_episode_it_cut(tmp_path, suffix, writer_process):
    """`stop` (what `simreel record` calls on Ctrl-C or an error): an `overwrite` recording stays in its side folder,
    the old file as it was; the running episode is noted as cut short, an ended one is not."""
    out = tmp_path / f"r{suffix}"
    zero = np.zeros(8, np.float32)
    for overwrite, steps in ((False, (3,)), (True, (50, 2))):  # 50: PickCube's time limit ends the episode
        rec = RecordWrapper(make_env("PickCube-v1"), out, overwrite=overwrite, writer_process=writer_process)
        for k, n in enumerate(steps):
            rec.reset(seed=k)
            for _ in range(n):
                rec.step(zero)
        if not overwrite:
            rec.close()
            old = out.read_bytes()
    rec.stop("a test")
    assert out.read_bytes() == old
    staged = tmp_path / f"r{suffix}.partial" / f"r{suffix}"
    with open_reader(out) as r:  # the old file's reader says where the new recording is (README, `stop`)
        assert r.notes == [f"a recording that was to replace this one stopped before it was complete; its committed "
                           f"episodes are in {staged} (this file is unchanged)"]
    with open_reader(staged) as r:
        assert [(m.length, m.notes) for m in r.episodes] == [
            (50, []), (2, ["cut short: a test stopped the recording before this episode ended"])]
    with pytest.raises(UsageError, match="holds the episodes of a recording that stopped before it was complete"):
        RecordWrapper(make_env("PickCube-v1"), out, overwrite=True, writer_process=writer_process)  # kept, not lost
    shutil.rmtree(tmp_path / f"r{suffix}.partial")
    rec = RecordWrapper(make_env("PickCube-v1"), out, overwrite=True, writer_process=writer_process)
    rec.reset(seed=0)
    for _ in range(50):
        rec.step(zero)
    rec.stop("a test")  # the episode ended at its last step: nothing is noted
    with open_reader(tmp_path / f"r{suffix}.partial" / f"r{suffix}") as r:
        assert [(m.length, m.notes) for m in r.episodes] == [(50, [])]


def _refusing(rec: RecordWrapper):
    """Make the next block the recorder takes break the layout (a field the recording does not list), so the sink
    refuses it, as it refuses any block that does not fit (`StepBlock.conform`); returns what undoes it."""
    buffer = rec._buffer
    buffer._arrays["bogus"] = np.zeros((buffer.capacity, rec.unwrapped.num_envs), np.float32)
    return lambda: buffer._arrays.pop("bogus")


@pytest.mark.parametrize("writer_process", [False, True])
def test_steps_the_sink_refuses_are_not_counted_and_an_episode_whose_end_is_refused_is_committed_by_stop(
        tmp_path, writer_process):
    """Regression: the steps of a refused block were counted in the episode's length before the sink took them (the
    file then said 5 steps and held 3), and a refused last block left its episode neither committed nor discarded."""
    from simreel.errors import EpisodeLayoutError

    for where in ("a block", "the last block"):
        path = tmp_path / f"{writer_process}-{where}.h5"
        rec = RecordWrapper(make_env("PickCube-v1"), path, writer_process=writer_process)
        rec.reset(seed=0)
        for k in range(5):
            rec.step(np.zeros(rec.action_space.shape, np.float32))
            if k == 2:
                rec._flush(0)  # steps 0-2 handed over
        undo = _refusing(rec)
        with pytest.raises(EpisodeLayoutError, match="bogus not in the recording's layout"):
            rec._flush(0) if where == "a block" else rec.reset(seed=1)  # steps 3-4 refused
        undo()
        rec.stop("an error (test)")
        with open_reader(path) as r:
            assert [m.index for m in r.episodes] == [0] and r.damaged == [], where
            episode = r.read_episode(0)
            assert episode.length == len(episode.actions) == 3, where
            assert "cut short" in " ".join(episode.meta.notes), where


@pytest.mark.parametrize("writer_process", [False, True])
@pytest.mark.parametrize("where", ["a block", "the last block"])
def test_an_episode_whose_steps_the_sink_refused_stops_there_even_for_a_caller_that_goes_on(
        tmp_path, writer_process, where):
    """Regression: a caller that caught the sink's refusal and stepped on got an episode with a hole (its later steps
    appended after the refused ones, the file calling it whole); the buffer then never filled again. Now the episode
    stops at the refused steps: step() says to reset, the reset commits the steps before them with a note, and the
    next episode records as usual."""
    from simreel.errors import EpisodeLayoutError

    path = tmp_path / "r.h5"
    rec = RecordWrapper(make_env("PickCube-v1"), path, writer_process=writer_process, block_steps=4)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(20, *rec.action_space.shape)).astype(np.float32)
    rec.reset(seed=0)
    for a in actions[:7]:  # steps 0-3 handed over with the first block
        rec.step(a)
    undo = _refusing(rec)
    with pytest.raises(EpisodeLayoutError, match="bogus"):  # steps 4-7, or 4-6, refused
        rec.step(actions[7]) if where == "a block" else rec.reset(seed=1)
    undo()
    with pytest.raises(UsageError, match=r"episode 0 .*stopped at step 4.*reset\(\)"):
        rec.step(actions[8])
    rec.reset(seed=1)
    for a in actions[9:18]:
        rec.step(a)
    rec.close()
    with open_reader(path) as r:
        first, second = r.read_episode(0), r.read_episode(1)
    assert first.length == 4 and np.array_equal(first.actions, actions[:4])
    assert first.meta.notes == ["cut short at step 4: the writer refused the steps from there on (episode 0: bogus "
                                "not in the recording's layout; describe every field in the RecordingMeta "
                                "(state_layout, obs_layout, info_layout, contact_channels, pose_bodies))"]
    assert second.length == 9 and np.array_equal(second.actions, actions[9:18]) and second.meta.notes == []


@pytest.mark.parametrize("end", ["close", "stop"])
def test_an_episode_whose_last_steps_close_or_stop_cannot_hand_over_keeps_the_steps_before_them(tmp_path, end):
    """Regression: a block refused while close() or stop() committed the running episodes ended their loop, and the
    writer closed with the episode still running: the steps handed over before were lost."""
    from simreel.errors import EpisodeLayoutError

    path = tmp_path / "r.h5"
    rec = RecordWrapper(make_env("PickCube-v1"), path, block_steps=4)
    rec.reset(seed=0)
    for _ in range(6):  # steps 0-3 handed over
        rec.step(np.zeros(rec.action_space.shape, np.float32))
    _refusing(rec)
    with pytest.raises(EpisodeLayoutError, match="bogus"):
        rec.close() if end == "close" else rec.stop("a test")
    with open_reader(path) as r:
        assert [(m.index, m.length) for m in r.episodes] == [(0, 4)]
        assert r.episodes[0].notes[-1].startswith("cut short at step 4: the writer refused the steps from there on")


@pytest.fixture(scope="module")
def level_task():
    """LiftCube with a second custom-state leaf, `level`, that a reset rebuilds from its options (another dtype or
    shape): a task whose state layout changes between episodes."""
    from mani_skill.utils.registration import register_env

    from simreel.tasks.lift_cube import LiftCubeEnv

    @register_env("SimreelTestLevel-v1", max_episode_steps=20)
    class Level(LiftCubeEnv):
        custom_state = ("goal_height", "level")

        def _load_scene(self, options):
            super()._load_scene(options)
            self.level = torch.zeros(self.num_envs, dtype=torch.float32)

        def _initialize_episode(self, env_idx, options):
            super()._initialize_episode(env_idx, options)
            if "level" in options:
                self.level = torch.full((self.num_envs, *options.get("shape", ())), options["level"])

    return "SimreelTestLevel-v1"


@pytest.mark.parametrize("change", [{"level": 16777217}, {"level": 1.0, "shape": (2,)}], ids=["dtype", "shape"])
def test_a_custom_leaf_that_changes_layout_is_refused_once_the_fast_reader_is_proven(tmp_path, level_task, change):
    """Regression: once the scene's fast reader was proven, its bit-for-bit check at a reset stood in for the layout
    check, but it compares the custom leaves only with the state just read: an int64 leaf was recorded cast to
    float32 (16777217 as 16777216.0), a reshaped one refused as a broken block rather than a changed layout."""
    rec = RecordWrapper(make_env(level_task), tmp_path / "r.h5", contacts="none")
    rec.reset(seed=0)
    for _ in range(2):  # the reader is proven after the first step
        rec.step(np.zeros(rec.action_space.shape, np.float32))
    with pytest.raises(StateLayoutError, match="level"):
        rec.reset(seed=1, options=change)
    rec.close()


class _ObsGrows(gym.Wrapper):
    """A plain wrapper below the recorder whose observations gain one number from step `at` of episode `episode` on
    (counted from 1), as a user's own wrapper might."""

    def __init__(self, env, *, at: int, episode: int | None = None):
        super().__init__(env)
        self.at, self.episode, self.resets, self.steps = at, episode, 0, 0

    def reset(self, **kwargs):
        self.resets, self.steps = self.resets + 1, 0
        return self.env.reset(**kwargs)

    def step(self, action):
        self.steps += 1
        obs, *rest = self.env.step(action)
        if self.steps >= self.at and self.episode in (None, self.resets):
            obs = torch.cat([obs, obs[:, :1]], dim=1)
        return (obs, *rest)


@pytest.mark.parametrize("writer_process", [False, True])
def test_an_observation_that_changes_shape_stops_its_episode_with_the_steps_before_it(tmp_path, writer_process):
    """Regression: an observation that gained a number mid-episode raised numpy's "could not broadcast (1,43) into
    (1,42)" at that step and at every later one, the episode never stopped. Now it is EpisodeLayoutError naming the
    field and both shapes; the episode is kept with its steps before that one and a note, step() says to reset, and
    the next episode records as usual."""
    from simreel.errors import EpisodeLayoutError

    path = tmp_path / "r.h5"
    rec = RecordWrapper(_ObsGrows(make_env("PickCube-v1"), at=7), path, record_obs=True, contacts="none",
                        writer_process=writer_process, block_steps=4)
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    for _ in range(6):  # steps 0-3 handed over with the first block, 4-5 buffered
        rec.step(zero)
    change = "obs/state: recorded (42,) float32, now (43,) float32"
    with pytest.raises(EpisodeLayoutError, match=re.escape(
            f"PickCube-v1: a step's rows do not fit the recording's layout ({change}), which every step keeps; "
            "episode 0 stops at step 6, kept with the steps before it; reset() to begin the next")):
        rec.step(zero)
    with pytest.raises(UsageError, match=re.escape("episode 0 (env 0) stopped at step 6: its rows did not fit the "
                                                   f"recording's layout ({change}); reset() to begin the next")):
        rec.step(zero)
    rec.reset(seed=1)
    assert [m.length for m in rec.episodes_committed] == [6]
    for _ in range(5):
        rec.step(zero)
    rec.close()
    with open_reader(path) as r:
        first, second = r.read_episode(0), r.read_episode(1)
    assert first.length == 6 and first.obs["state"].shape == (7, 42)
    assert first.meta.notes == [f"cut short at step 6: its rows did not fit the recording's layout ({change})"]
    assert second.length == 5 and second.meta.notes == []


class _ObsLosesExtra(gym.Wrapper):
    """A plain wrapper below the recorder whose dict observations lose their "extra" entries from step `at` on."""

    def __init__(self, env, *, at: int):
        super().__init__(env)
        self.at, self.steps = at, 0

    def reset(self, **kwargs):
        self.steps = 0
        return self.env.reset(**kwargs)

    def step(self, action):
        self.steps += 1
        obs, *rest = self.env.step(action)
        return ({k: v for k, v in obs.items() if k != "extra" or self.steps < self.at}, *rest)


def test_an_observation_that_loses_a_key_stops_its_episode_instead_of_recording_stale_rows(tmp_path):
    """Regression: observations that lost a key mid-episode raised nothing; the block kept that field's rows as they
    were (np.empty's garbage), and the file recorded them as observations. Now it is EpisodeLayoutError naming the
    fields now absent, and the episode keeps only the steps that had them."""
    from simreel.errors import EpisodeLayoutError

    path = tmp_path / "r.h5"
    rec = RecordWrapper(_ObsLosesExtra(make_env("PickCube-v1", obs_mode="state_dict"), at=3), path, record_obs=True,
                        contacts="none")
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    rec.step(zero)
    rec.step(zero)
    with pytest.raises(EpisodeLayoutError, match=re.escape("obs/extra/goal_pos: recorded (3,) float32, now absent")):
        rec.step(zero)
    rec.close()
    with open_reader(path) as r:
        episode = r.read_episode(0)
    assert episode.length == 2 and np.isfinite(episode.obs["extra/tcp_pose"]).all()
    assert episode.meta.notes[0].startswith("cut short at step 2: its rows did not fit the recording's layout")


def test_a_block_refused_for_its_first_rows_leaves_the_next_episode_recordable(tmp_path):
    """Regression: the buffer shapes each field after the first row pushed; where that row did not fit, the writer
    refused the block, and every later step raised numpy's broadcast error, in later episodes too."""
    from simreel.errors import EpisodeLayoutError

    path = tmp_path / "r.h5"
    rec = RecordWrapper(_ObsGrows(make_env("PickCube-v1"), at=1, episode=1), path, record_obs=True, contacts="none",
                        block_steps=4)
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    for _ in range(3):
        rec.step(zero)
    with pytest.raises(EpisodeLayoutError, match=re.escape("obs/state has shape (4, 43), expected (4, 42)")):
        rec.step(zero)
    rec.reset(seed=1)
    for _ in range(5):
        rec.step(zero)
    rec.close()
    with open_reader(path) as r:
        assert [(m.seed, m.length) for m in r.episodes] == [(1, 5)]  # the first had no step that fit


def test_a_numpy_action_of_a_dtype_maniskill_cannot_step_with_is_refused_before_the_env_steps(tmp_path):
    """Regression: a numpy uint64 action failed inside ManiSkill's step with torch's NotImplementedError
    ("clamp_scalar_cpu" not implemented for 'UInt64'), a longdouble one with torch's TypeError. The other numpy dtypes
    ManiSkill steps with (uint16 and uint32 it widens first, float16, bool) are recorded as given."""
    from simreel.errors import ActionError

    rec = RecordWrapper(make_env("PickCube-v1"), tmp_path / "a.h5", contacts="none", writer_process=False)
    rec.reset(seed=0)
    refused = [(np.uint64, "an action of dtype uint64, which ManiSkill cannot clip to the action space; give float32 "
                           "actions"),
               (np.longdouble, f"an action of dtype {np.dtype(np.longdouble)}, which torch, and so ManiSkill, cannot "
                               "take; give float32 actions")]
    for dtype, message in refused:
        for shape in ((8,), (1, 8)):
            with pytest.raises(ActionError, match=f"^{re.escape(message)}$"):
                rec.step(np.ones(shape, dtype))
    taken = [np.ones(8, dtype) for dtype in (np.uint16, np.uint32, np.float16, np.int8, bool)]
    for action in taken:
        rec.step(action)
    rec.close()
    with open_reader(tmp_path / "a.h5") as r:
        episode = r.read_episode(0)
    assert episode.length == len(taken) and np.array_equal(episode.actions, np.ones((len(taken), 8), np.float32))


_DROPPED_RECORDER = """
import sys
import numpy as np
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env

env = RecordWrapper(make_env("PickCube-v1", max_episode_steps=5), sys.argv[1], contacts="none")
zero = np.zeros(env.action_space.shape, np.float32)
for seed in (0, 1):
    env.reset(seed=seed)
    for _ in range(3):
        env.step(zero)
print("dropped")  # the script ends without env.close()
"""


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_a_recorder_dropped_without_close_leaves_what_a_crash_leaves(tmp_path, suffix):
    """The README's promise for a script that ends without close(): the committed episode stays, the running one is
    lost and named (by inspect for HDF5, by recover for MCAP, whose file then has no footer)."""
    import subprocess
    import sys

    from simreel.errors import RecordingFileError

    path = tmp_path / f"r{suffix}"
    run = subprocess.run([sys.executable, "-c", _DROPPED_RECORDER, str(path)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0 and "dropped" in run.stdout, run.stderr
    simreel = [sys.executable, "-m", "simreel"]
    if suffix == ".h5":
        with open_reader(path) as r:
            assert [m.length for m in r.episodes] == [3]
        inspect = subprocess.run([*simreel, "inspect", str(path)], capture_output=True, text=True, timeout=120)
        assert inspect.returncode == 0 and "were still running" in inspect.stderr + inspect.stdout
        assert "episode 1 (env 0, seed 1" in inspect.stderr + inspect.stdout
        return
    with pytest.raises(RecordingFileError, match="no footer.*simreel recover"):
        open_reader(path)
    out = tmp_path / "recovered.mcap"
    recover = subprocess.run([*simreel, "recover", str(path), "-o", str(out)], capture_output=True, text=True,
                             timeout=120)
    assert recover.returncode == 0, recover.stderr
    assert "recovered 1 committed episode(s), 3 steps" in recover.stdout + recover.stderr
    assert "lost (never committed): episode 1" in recover.stdout + recover.stderr
    with open_reader(out) as r:
        assert [m.length for m in r.episodes] == [3]
