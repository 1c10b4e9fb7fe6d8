"""The scene fingerprint of real envs: what it holds, that it is stable, and that every difference is named."""

from __future__ import annotations

import json

import pytest

from simreel.sim.fingerprint import (
    SceneDifference,
    apply_changes,
    fingerprint_changes,
    scene_differences,
    scene_fingerprint,
)
from simreel.sim.make import make_env


@pytest.fixture(scope="module")
def lift():
    env = make_env("SimreelLiftCube-v1", render_backend="none")
    env.reset(seed=0)
    yield env.unwrapped
    env.close()


def test_it_holds_masses_shapes_materials_joints_and_controllers(lift):
    fp = scene_fingerprint(lift)
    cube = fp["bodies"]["cube"]
    assert (cube["type"], cube["mass"]) == ("dynamic", 0.064)
    assert cube["inertia"] == [pytest.approx(1.7066666e-05)] * 3
    (box,) = cube["shapes"]
    assert (box["shape"], box["half_size"]) == ("box", [0.02, 0.02, 0.02])
    assert (box["static_friction"], box["dynamic_friction"], box["restitution"]) == (0.3, 0.3, 0.0)
    assert fp["bodies"]["ground"]["shapes"][0]["shape"] == "plane"
    link = fp["bodies"]["panda/panda_link1"]
    assert link["shapes"][0]["shape"] == "convex_mesh" and len(link["shapes"][0]["mesh"]) == 16
    assert link["joint"]["type"].startswith("revolute")
    assert (link["joint"]["stiffness"], link["joint"]["damping"]) == (1000.0, 100.0)
    arm = fp["controllers"]["panda"]["arm"]
    assert (arm["class"], arm["stiffness"], arm["pos_lower"]) == ("PDEEPosController", 1000.0, -0.1)
    assert "urdf_path" not in arm  # a file on the recording machine, not physics
    assert json.loads(json.dumps(fp)) == fp  # plain JSON, stored as it is
    assert scene_fingerprint(lift) == fp  # the same scene, the same numbers


def test_a_heavier_cube_is_named_by_its_mass():
    env = make_env("SimreelLiftCube-v1", render_backend="none", env_kwargs={"cube_mass": 0.08})
    try:
        heavy = scene_fingerprint(env.unwrapped)
    finally:
        env.close()
    env = make_env("SimreelLiftCube-v1", render_backend="none")
    try:
        light = scene_fingerprint(env.unwrapped)
    finally:
        env.close()
    diffs = scene_differences(light, heavy)
    assert diffs[0] == SceneDifference("cube", "mass", 0.064, 0.08)
    assert [d.describe() for d in diffs] == [
        "cube: mass 0.064 → 0.08",
        "cube: inertia [1.71e-05, 1.71e-05, 1.71e-05] → [2.13e-05, 2.13e-05, 2.13e-05]",
    ]
    assert diffs[0].to_json() == {"subject": "cube", "property": "mass", "recorded": 0.064, "replaying": 0.08,
                                  "text": "cube: mass 0.064 → 0.08"}


def test_a_rebuilt_scene_is_kept_as_its_changes():
    env = make_env("SimreelHeteroDrawer-v1", render_backend="none")
    try:
        u = env.unwrapped
        env.reset(seed=0, options={"reconfigure": True})
        first = scene_fingerprint(u)
        env.reset(seed=1, options={"reconfigure": True})
        second = scene_fingerprint(u)
    finally:
        env.close()
    changes = fingerprint_changes(first, second)
    assert set(changes) == {"bodies"}  # the robot, table and controllers are the same
    assert all(name.startswith("cabinet") for name in changes["bodies"])
    assert apply_changes(first, changes) == second
    assert fingerprint_changes(first, first) == {}
    texts = [d.describe() for d in scene_differences(first, second)]
    assert texts and all(t.startswith("cabinet") for t in texts)


def test_differences_format_just_enough_digits():
    assert SceneDifference("cube", "mass", 1.0, 1.0000001).describe() == "cube: mass 1 → 1.0000001"
    assert SceneDifference("table", "", "present", None).describe() == "table: only in the recording"
    assert SceneDifference("controller panda/arm", "stiffness", 1000.0, 500.0).describe() == \
        "controller panda/arm: stiffness 1000 → 500"


def test_it_holds_a_hash_of_each_task_class_source_file(lift):
    code = scene_fingerprint(lift)["code"]
    assert list(code)[0] == "LiftCubeEnv" and "BaseEnv" in code  # the task's own class first, up to ManiSkill's
    assert all(len(digest) == 16 for digest in code.values())
    older = {section: entries for section, entries in scene_fingerprint(lift).items() if section != "code"}
    assert scene_differences(older, scene_fingerprint(lift)) == []  # recorded before simreel kept it: not compared


REWARD_TASK = """
from mani_skill.utils.registration import register_env
from simreel.tasks.lift_cube import LiftCubeEnv

REWARD_SCALE = {scale}


@register_env("SimreelTestScaledReward-v1", max_episode_steps=20)
class ScaledReward(LiftCubeEnv):
    def compute_dense_reward(self, obs, action, info):
        return REWARD_SCALE * super().compute_dense_reward(obs, action, info)
"""


def test_a_task_whose_code_changed_since_the_recording_is_named(tmp_path):
    """Its reward is scaled by a constant of its file: a change no state comparison can name, the code hash does."""
    import subprocess
    import sys

    from simreel.cli.main import main

    task, recording = tmp_path / "scaled.py", tmp_path / "scaled.h5"
    task.write_text(REWARD_TASK.format(scale=1.0))
    assert main(["record", "SimreelTestScaledReward-v1", "--import", str(task), "-n", "1", "--max-steps", "5",
                 "-o", str(recording), "-q"]) == 0
    task.write_text(REWARD_TASK.format(scale=1.5))
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", str(recording), "-q",
                           "--trust-recorded-imports"], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "why: the replaying scene differs from the recorded one (task code ScaledReward: source file hash" \
        in done.stdout, done.stdout
