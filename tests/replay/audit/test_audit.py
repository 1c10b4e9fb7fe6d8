"""`simreel audit`: the leaky example task is flagged with the key and the cause; its fixed twin passes."""

from __future__ import annotations

import json

from simreel.cli.main import main


def test_leaky_task_is_flagged(tmp_path, capsys):
    out = tmp_path / "audit.json"
    assert main(["audit", "SimreelLiftCubeLeaky-v1", "--import", "simreel.tasks", "--json", str(out)]) == 1
    text = capsys.readouterr().out
    assert "evaluate()['height_error'] differs after restore: task state not in the state dict — declare it" in text
    assert "goal_height" in text  # the attribute that holds the leaked state is named
    doc = json.loads(out.read_text())
    assert doc["ok"] is False
    keys = {(f["kind"], f["key"]) for f in doc["findings"]}
    assert ("restore_evaluate", "info/height_error") in keys
    assert ("restore_obs", "obs/extra/goal_height") in keys
    assert all({"kind", "key", "detail"} <= set(f) for f in doc["findings"])


def test_fixed_twin_passes(tmp_path, capsys):
    out = tmp_path / "audit.json"
    assert main(["audit", "SimreelLiftCube-v1", "--json", str(out), "--steps", "10"]) == 0
    assert "no findings" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["ok"] is True and doc["findings"] == []
    assert any("round-trips" in c for c in doc["checks"])
    assert "state-dict layout is the same as built and for seeds 0, 1, 2" in doc["checks"]


def test_controller_state_is_checked(capsys):
    assert main(["audit", "PickCube-v1", "--control-mode", "pd_ee_target_delta_pos", "--steps", "8"]) == 0
    out = capsys.readouterr().out
    assert "controller state survives a restore (controller/arm/target_pose)" in out
    assert "ManiSkill's set_state_dict() ignores the controller state" in out


def test_a_real_leak_in_a_builtin_task_is_found(capsys):
    """ManiSkill 3.0.1's RotateValve samples the valve's rest position per episode into `rest_qpos`, which its
    state dict does not hold: after a restore, the valve rotation (and the reward) follow the other episode."""
    assert main(["audit", "RotateValveLevel0-v1", "--steps", "5", "-q"]) == 1
    out = capsys.readouterr().out
    assert "restore_evaluate   info/valve_rotation" in out
    assert "task attributes that still differ after the restore: rest_qpos" in out


UNBOUNDED_CABINET_TASK = """
import numpy as np, sapien, torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.registration import register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from simreel.authoring.heterogeneous import build_heterogeneous_articulation
from simreel.tasks.cabinets import add_cabinet_links, sample_cabinet

@register_env("SimreelTestUnboundedCabinet-v1", max_episode_steps=20)
class UnboundedCabinet(BaseEnv):
    \"\"\"A cabinet of 1 or 2 joints per episode, merged without a state_dof bound: its layout follows the seed.\"\"\"
    SUPPORTED_ROBOTS = ["panda"]

    def __init__(self, *args, robot_uids="panda", **kwargs):
        super().__init__(*args, robot_uids=robot_uids, reconfiguration_freq=1, **kwargs)

    def _load_agent(self, options):
        super()._load_agent(options, sapien.Pose(p=[-0.615, 0, 0]))

    def _load_scene(self, options):
        self.table_scene = TableSceneBuilder(self)
        self.table_scene.build()
        seeds = self._batched_episode_rng.randint(0, 2**31 - 1)
        specs = [sample_cabinet(np.random.RandomState(int(s))) for s in seeds]
        self.cab = build_heterogeneous_articulation(self.scene, lambda b, i: add_cabinet_links(b, specs[i], None),
                                                    name="cab", state_dof=None, merged_links=["handle"],
                                                    initial_pose=sapien.Pose(p=[0.1, 0, 0]))

    def _initialize_episode(self, env_idx, options):
        self.table_scene.initialize(env_idx)

    def evaluate(self):
        return {"success": torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)}

    def compute_dense_reward(self, obs, action, info):
        return torch.zeros(self.num_envs, device=self.device)

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info)
"""


def test_a_layout_that_differs_from_the_built_one_is_found(tmp_path, capsys):
    """Seeds 0-2 all give this cabinet one joint, the env as gym.make built it (ManiSkill's own seed) two: the
    audit compared seeds only and said "no findings", while a recorder made after gym.make refused every episode."""
    task = tmp_path / "unbounded_cabinet.py"
    task.write_text(UNBOUNDED_CABINET_TASK)
    assert main(["audit", "SimreelTestUnboundedCabinet-v1", "--import", str(task), "--steps", "3", "-q"]) == 1
    out = capsys.readouterr().out
    assert "layout_build       env_states/articulations/cab" in out
    assert "as gym.make built it and (15,) float32 after reset(seed=0)" in out


GLOBAL_RNG_TASK = """
import numpy as np
from mani_skill.utils.registration import register_env
from simreel.tasks.lift_cube import LiftCubeEnv

@register_env("SimreelTestGlobalRng-v1", max_episode_steps=20)
class GlobalRng(LiftCubeEnv):
    \"\"\"Moves the cube by a draw of numpy's global RNG at every reset: no seed reproduces an episode.\"\"\"
    def _initialize_episode(self, env_idx, options):
        super()._initialize_episode(env_idx, options)
        p = self.cube.pose.p.clone()
        p[:, 1] += float(np.random.uniform(-0.05, 0.05))
        self.cube.set_pose(type(self.cube.pose).create_from_pq(p, self.cube.pose.q))
"""


def test_a_reset_the_seed_does_not_reproduce_is_found(tmp_path, capsys):
    """Restoring its state dict restores everything this task computes, so the restore checks pass; but its reset
    draws from numpy's global RNG, and a replay, which starts each episode from its seed, never reproduces it."""
    task = tmp_path / "global_rng.py"
    task.write_text(GLOBAL_RNG_TASK)
    out = tmp_path / "audit.json"
    assert main(["audit", "SimreelTestGlobalRng-v1", "--import", str(task), "--steps", "3", "--json", str(out)]) == 1
    assert "reset(seed=0) gives another initial state than it gave before" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert {(f["kind"], f["key"]) for f in doc["findings"]} == {("reset_seed", "env_states/actors/cube[p]")}
