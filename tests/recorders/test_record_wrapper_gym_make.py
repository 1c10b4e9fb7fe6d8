"""RecordWrapper around the user's own ``gym.make`` (not simreel's make_env), the way the README shows it: on a
machine set up by `make setup` (lavapipe), with state and with camera observations; and with no render device
at all, state-only (ManiSkill itself then needs ``render_backend="none"``).

Each case is a fresh process: which Vulkan driver SAPIEN sees is decided when it first loads.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import json, sys
    import gymnasium as gym, mani_skill.envs
    from simreel.recorders import RecordWrapper
    from simreel.formats import open_reader

    out = {}
    for obs_mode, extra in json.loads(sys.argv[2]):
        path = f"{sys.argv[1]}/{obs_mode}.h5"
        env = RecordWrapper(gym.make("PickCube-v1", obs_mode=obs_mode, **extra), path, record_obs=True)
        env.reset(seed=0)
        for _ in range(5):
            env.step(env.action_space.sample())
        env.close()
        with open_reader(path) as r:
            ep = r.read_episode(0)
            out[obs_mode] = {"steps": ep.length, "obs": {k: list(v.shape) for k, v in ep.obs.items()},
                             "render_backend": r.meta.render_backend}
    print(json.dumps(out))
    """
)


def _record(env: dict[str, str], tmp_path, cases: list) -> dict:
    done = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), json.dumps(cases)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_plain_gym_make_records_state_and_camera_observations_on_lavapipe(lavapipe_env, tmp_path):
    out = _record(lavapipe_env, tmp_path, [["state", {}], ["rgb", {}]])
    assert out["state"]["steps"] == 5 and out["state"]["obs"]["state"] == [6, 42]
    assert out["rgb"]["steps"] == 5 and out["rgb"]["obs"]["sensor_data/base_camera/rgb"] == [6, 128, 128, 3]


def test_plain_gym_make_records_state_only_without_any_render_device(no_render_env, tmp_path):
    out = _record(no_render_env, tmp_path, [["state", {"render_backend": "none"}]])
    assert out["state"] == {"steps": 5, "obs": {"state": [6, 42]}, "render_backend": "none"}


@pytest.mark.parametrize("obs_mode", ["state"])
def test_without_simreel_imported_first_plain_gym_make_has_no_device_here(lavapipe_env, obs_mode):
    """Why importing simreel matters on a CPU machine: without it, SAPIEN finds no Vulkan driver at all."""
    script = (f"import gymnasium as gym, mani_skill.envs\ntry:\n    gym.make('PickCube-v1', obs_mode='{obs_mode}')\n"
              "except RuntimeError as e:\n    print('refused:', e)\n")
    env = {k: v for k, v in lavapipe_env.items() if k != "SIMREEL_VK_ICD"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert "refused:" in done.stdout and "ErrorIncompatibleDriver" in done.stdout
