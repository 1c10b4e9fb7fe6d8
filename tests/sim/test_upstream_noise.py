"""`simreel.sim.upstream_noise`: a user's script that imports simreel.recorders.RecordWrapper prints none of the upstream messages
that ask nothing of them (SAPIEN's libvulkan fallback, ManiSkill's sapien_cuda fallback), and shows them again with
SIMREEL_SHOW_UPSTREAM_WARNINGS=1."""

from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = """
import gymnasium as gym
from simreel.recorders import RecordWrapper  # prepares gym.make, and quiets the known upstream messages
import mani_skill.envs
env = gym.make("PickCube-v1", obs_mode="state")  # the default render device: sapien_cuda, then a fallback
env.reset(seed=0)
env.close()
print("built")
"""

NOISE = ("Failed to find system libvulkan", 'Requested to use render device "sapien_cuda"')


@pytest.mark.parametrize("shown", [False, True], ids=["quiet", "shown"])
def test_a_users_script_prints_no_known_upstream_noise(tmp_path, lavapipe_env, shown):
    env = {**lavapipe_env, "SIMREEL_SHOW_UPSTREAM_WARNINGS": "1" if shown else ""}
    env.pop("VK_ICD_FILENAMES", None)  # as a user's shell has it: simreel points Vulkan at its driver itself
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "built", done.stderr
    assert [n for n in NOISE if n in done.stderr] == (list(NOISE) if shown else []), done.stderr
