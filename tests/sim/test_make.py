"""simreel.sim.make: building real ManiSkill envs with lavapipe and with no render device at all.

Vulkan must be configured before sapien loads, so each render mode runs in its own subprocess; the
no-device subprocess builds every env once and the tests below read its JSON answer.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from simreel.sim.make import camera_use, env_versions

REPO = Path(__file__).resolve().parents[2]
STATE_ONLY_TASKS = ["PickCube-v1", "StackCube-v1", "PegInsertionSide-v1", "RotateValveLevel0-v1"]

NO_DEVICE_SCRIPT = textwrap.dedent(
    """
    import json, sys, warnings
    from simreel.sim import norender, render_device
    from simreel.sim.make import make_env
    from simreel.sim.user_code import import_user_code
    from simreel.errors import SimreelError

    def error(env_id, **kwargs):
        try:
            make_env(env_id, **kwargs)
        except SimreelError as exc:
            return [type(exc).__name__, str(exc)]
        return None

    out = {"backend": render_device.detect_render_backend(), "envs": {}}
    out["unknown_no_import"] = error("PickCub-v1")
    user_module = import_user_code(sys.argv[1])
    for env_id in sys.argv[2:]:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            env = make_env(env_id)
        if env_id == sys.argv[2]:
            out["version_warnings"] = [str(w.message) for w in caught if w.category is norender.NoRenderVersionWarning]
        obs, _ = env.reset(seed=0)
        before = env.unwrapped.get_state_dict()
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        after = env.unwrapped.get_state_dict()
        out["envs"][env_id] = {
            "obs_shape": list(obs.shape),
            "render_backend": env.unwrapped.backend.render_backend,
            "state": {f"{group}/{name}": list(v.shape) for group in after for name, v in after[group].items()},
            "moved": any(not (after[g][n] == before[g][n]).all() for g in after for n in after[g]),
        }
        env.close()
    out["norender_installed"] = norender.is_installed()
    out["user_module_material"] = user_module.RenderMaterial.__name__
    out["rgb"] = error("PickCube-v1", obs_mode="rgb")
    out["render_mode"] = error("PickCube-v1", env_kwargs={"render_mode": "rgb_array"})
    out["push_t"] = error("PushT-v1")
    out["unknown"] = error("PickCub-v1")
    out["bad_control_mode"] = error("PickCube-v1", control_mode="bogus")
    out["bad_kwarg"] = error("PickCube-v1", env_kwargs={"bogus_kwarg": 1})
    out["repeated_kwarg"] = error("PickCube-v1", control_mode="pd_joint_pos",
                                  env_kwargs={"control_mode": "pd_ee_delta_pos"})
    env = make_env("PickCube-v1", env_kwargs={"sim_config": {"sim_freq": 400}, "control_mode": "pd_joint_pos"})
    out["folded_kwargs"] = [env.unwrapped.sim_freq, env.unwrapped.control_mode]
    env.close()
    out["rgb_none"] = error("PickCube-v1", obs_mode="rgb", render_backend="none")
    import os
    os.environ["VK_ICD_FILENAMES"] = "/nonexistent/icd.json"  # the user's choice, after the probe: it names no file
    out["rgb_user_icd"] = error("PickCube-v1", obs_mode="rgb")
    out["num_envs"] = error("PickCube-v1", num_envs=2)
    print(json.dumps(out))
    """
)

LAVAPIPE_SCRIPT = textwrap.dedent(
    """
    import json
    from simreel.sim import norender, render_device
    from simreel.sim.make import make_env
    env = make_env("PickCube-v1", obs_mode="rgb")
    obs, _ = env.reset(seed=0)
    rgb = obs["sensor_data"]["base_camera"]["rgb"]
    print(json.dumps({
        "backend": render_device.detect_render_backend(),
        "render_backend": env.unwrapped.backend.render_backend,
        "norender_installed": norender.is_installed(),
        "shape": list(rgb.shape), "dtype": str(rgb.dtype),
        "distinct_values": int(rgb.unique().numel()),
    }))
    """
)


CUSTOM_TASK = textwrap.dedent(
    """
    from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
    from mani_skill.utils.registration import register_env
    from sapien.render import RenderMaterial  # bound before make_env: must be swapped too

    @register_env("SimreelTestPickCube-v1", max_episode_steps=10)
    class SimreelTestPickCube(PickCubeEnv):
        pass
    """
)


def _start(script: str, args: list[str], env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", script, *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _answer(child: subprocess.Popen[str]) -> dict:
    out, err = child.communicate(timeout=300)
    assert child.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def task_file(tmp_path_factory) -> Path:
    """The user's task module that the no-device subprocess imports (registers SimreelTestPickCube-v1)."""
    path = tmp_path_factory.mktemp("user_code") / "my_tasks.py"
    path.write_text(CUSTOM_TASK)
    return path


@pytest.fixture(scope="module")
def children(request, no_render_env, task_file) -> Iterator[dict[str, subprocess.Popen[str] | str]]:
    """Both render modes' subprocesses, started together so they overlap; a skip reason where one cannot run."""
    started: dict[str, subprocess.Popen[str] | str] = {
        "no_device": _start(NO_DEVICE_SCRIPT, [str(task_file), *STATE_ONLY_TASKS, "SimreelTestPickCube-v1"],
                            no_render_env),
    }
    try:
        started["lavapipe"] = _start(LAVAPIPE_SCRIPT, [], request.getfixturevalue("lavapipe_env"))
    except pytest.skip.Exception as skipped:
        started["lavapipe"] = str(skipped)
    yield started
    for child in started.values():
        if isinstance(child, subprocess.Popen) and child.poll() is None:
            child.kill()
            child.communicate()


@pytest.fixture(scope="module")
def no_device(children) -> dict:
    return _answer(children["no_device"])


def test_no_device_is_detected(no_device):
    assert no_device["backend"] == "none"
    assert no_device["norender_installed"] is True
    assert no_device["version_warnings"] == []  # the pinned versions are installed


def test_no_render_layer_swaps_names_bound_in_user_code(no_device):
    assert no_device["user_module_material"] == "InertRenderMaterial"


@pytest.mark.parametrize("env_id", [*STATE_ONLY_TASKS, "SimreelTestPickCube-v1"])
def test_state_only_envs_reset_step_and_give_state(no_device, env_id):
    built = no_device["envs"][env_id]
    assert built["render_backend"] == "none"
    assert built["obs_shape"][0] == 1 and len(built["obs_shape"]) == 2
    assert built["moved"] is True
    assert any(key.startswith("articulations/") for key in built["state"])
    for key, shape in built["state"].items():
        # actors: 13 floats; articulations: 13 + 2 * dof
        assert shape[0] == 1 and (shape[1] == 13 or key.startswith("articulations/")), (key, shape)


def test_peg_insertion_state_uses_merged_views(no_device):
    state = no_device["envs"]["PegInsertionSide-v1"]["state"]
    assert state["actors/peg"] == [1, 13] and state["actors/box_with_hole"] == [1, 13]
    assert state["articulations/panda_wristcam"] == [1, 31]


def _no_device_help(no_render_env) -> str:
    """What the refusals tell a user to do: fetch lavapipe where this process looks for it (the test's
    SIMREEL_VK_ICD names a missing file of another name, so the message says to point SIMREEL_VK_ICD at it)."""
    folder = Path(no_render_env["SIMREEL_VK_ICD"]).parent
    lavapipe = ("fetch the software Vulkan driver (lavapipe): `make setup` does it in a simreel checkout; after a pip "
                f"install run `tools/fetch_lavapipe.sh {folder} and set SIMREEL_VK_ICD={folder}/lvp_icd.json` from "
                "simreel's source (Debian/Ubuntu)")
    if not any(os.path.exists(p) for p in ("/dev/nvidia0", "/proc/driver/nvidia")):
        return f"{lavapipe}; or use a machine with a GPU"
    return ("make this machine's NVIDIA Vulkan driver usable (SAPIEN finds no Vulkan device on the GPU: install the "
            "Vulkan loader, libvulkan1, and in a container grant the graphics driver capability, e.g. "
            f"NVIDIA_DRIVER_CAPABILITIES=all); or render on the CPU: {lavapipe}, then set VK_ICD_FILENAMES to its "
            "lvp_icd.json (simreel does not choose lavapipe itself where an NVIDIA GPU is present)")


@pytest.fixture(scope="module")
def placeholders(no_render_env, task_file) -> dict[str, str]:
    """What the expected messages below leave open: the help clause and the user's task file."""
    return {"help": _no_device_help(no_render_env), "user_file": str(task_file)}


@pytest.mark.parametrize(
    ("case", "kind", "message"),
    [
        ("rgb", "RenderUnavailableError",
         "PickCube-v1: obs_mode='rgb' needs camera images (rgb), but there is no render device "
         "(no Vulkan device SAPIEN can render with). To render, {help}; or use obs_mode='state' and no render_mode."),
        ("render_mode", "RenderUnavailableError",
         "PickCube-v1: render_mode='rgb_array' renders images, but there is no render device "
         "(no Vulkan device SAPIEN can render with). To render, {help}; or use obs_mode='state' and no render_mode."),
        ("push_t", "RenderUnavailableError",
         "PushT-v1 cannot be built without a render device: it un-textures the table by reading the render "
         "shapes of its render body, which is never built without a render device. To build it, {help}."),
        ("unknown_no_import", "EnvBuildError",
         "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1, PickCubeSO100-v1, PokeCube-v1? "
         "(a custom task must be registered first: pass --import MODULE_OR_FILE.py)"),
        ("unknown", "EnvBuildError",
         "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1, PickCubeSO100-v1, PokeCube-v1? "
         "(the code imported does not register it: {user_file} registers SimreelTestPickCube-v1)"),
        ("repeated_kwarg", "EnvBuildError",
         "PickCube-v1: control_mode is given twice, 'pd_joint_pos' and 'pd_ee_delta_pos' in env_kwargs "
         "(--env-kwargs); give it once"),
        ("rgb_none", "RenderUnavailableError",
         "PickCube-v1: obs_mode='rgb' needs camera images (rgb), but there is no render device (render_backend='none' "
         "was asked for). To render, ask for one: drop --render-backend none (render_backend='none' asks for no "
         "device); or use obs_mode='state' and no render_mode."),
        ("rgb_user_icd", "RenderUnavailableError",
         "PickCube-v1: obs_mode='rgb' needs camera images (rgb), but there is no render device (no Vulkan device "
         "SAPIEN can render with). To render, fix or unset VK_ICD_FILENAMES=/nonexistent/icd.json "
         "(/nonexistent/icd.json does not exist; unset, simreel uses the lavapipe `make setup` fetched); or use "
         "obs_mode='state' and no render_mode."),
        ("num_envs", "EnvBuildError",
         "PickCube-v1: num_envs=2 needs the GPU sim (PhysX CUDA) and this machine has no CUDA device; use "
         "num_envs=1 (CPU sim), or gymnasium's AsyncVectorEnv for several CPU envs"),
    ],
)
def test_errors_without_a_device(no_device, placeholders, case, kind, message):
    assert no_device[case] == [kind, message.format(**placeholders)]


def test_named_arguments_in_env_kwargs_are_taken_as_those_arguments(no_device):
    """What a CLI user can only give through --env-kwargs (sim_config), or gives there instead of its own option."""
    assert no_device["folded_kwargs"] == [400, "pd_joint_pos"]


def test_the_fetch_command_a_refusal_names_exists_and_fills_the_folder_simreel_reads(no_device, no_render_env):
    """The pip-install advice names this repository's script and the folder whose lvp_icd.json simreel reads."""
    import shlex

    message = no_device["rgb"][1]
    command = message.split("run `", 1)[1].split("`", 1)[0]
    script, folder, *rest = shlex.split(command)
    assert (REPO / script).is_file() and "lvp_icd.json" in (REPO / script).read_text()
    assert rest == ["and", "set", f"SIMREEL_VK_ICD={folder}/lvp_icd.json"]
    assert folder == str(Path(no_render_env["SIMREEL_VK_ICD"]).parent)


def test_bad_kwargs_keep_maniskills_message(no_device):
    kind, message = no_device["bad_kwarg"]
    assert kind == "EnvBuildError"
    assert message.startswith("PickCube-v1: could not build the env: TypeError: BaseEnv.__init__() got an "
                              "unexpected keyword argument 'bogus_kwarg'")
    assert "\n" not in message


def test_a_control_mode_the_robot_lacks_is_named_before_the_build(no_device):
    """Was ManiSkill's assertion, from inside the build: `simreel.sim.modes`."""
    assert tuple(no_device["bad_control_mode"]) == (
        "EnvBuildError", "PickCube-v1: no control mode 'bogus'; the control modes there are pd_joint_delta_pos, "
        "pd_joint_pos, pd_ee_delta_pos, pd_ee_delta_pose, pd_ee_pose, pd_joint_target_delta_pos, "
        "pd_ee_target_delta_pos, pd_ee_target_delta_pose, pd_joint_vel, pd_joint_pos_vel, pd_joint_delta_pos_vel")


def test_lavapipe_renders_camera_observations(children):
    if isinstance(children["lavapipe"], str):
        pytest.skip(children["lavapipe"])
    out = _answer(children["lavapipe"])
    assert out["backend"] == "cpu" and out["render_backend"] == "sapien_cpu"
    assert out["norender_installed"] is False
    assert out["shape"] == [1, 128, 128, 3] and out["dtype"] == "torch.uint8"
    assert out["distinct_values"] > 10  # a real picture, not a blank frame


@pytest.mark.parametrize(
    ("obs_mode", "render_mode", "expected"),
    [
        ("state", None, None),
        ("state_dict", None, None),
        ("none", None, None),
        ("rgb", None, "obs_mode='rgb' needs camera images (rgb)"),
        ("rgb+depth+segmentation", None, "obs_mode='rgb+depth+segmentation' needs camera images "
                                          "(depth, rgb, segmentation)"),
        ("pointcloud", None, "obs_mode='pointcloud' needs camera images (pointcloud)"),
        ("sensor_data", None, "obs_mode='sensor_data' needs camera images (sensor_data)"),
        ("state", "rgb_array", "render_mode='rgb_array' renders images"),
    ],
)
def test_camera_use(obs_mode, render_mode, expected):
    assert camera_use(obs_mode, render_mode) == expected


def test_env_versions_from_metadata():
    versions = env_versions()
    assert set(versions) == {"simreel", "mani_skill", "sapien", "torch", "numpy", "gymnasium", "python"}
    assert versions["mani_skill"] == "3.0.1" and versions["sapien"] == "3.0.3"
    assert versions["python"] == "{}.{}.{}".format(*sys.version_info[:3])


def test_a_gpu_build_without_the_physx_gpu_library_says_where_to_get_it_and_put_it(tmp_path):
    """SAPIEN fetches its PhysX GPU library from GitHub when a process first uses the GPU sim; on a machine that cannot
    reach GitHub (this one, CI, the lent GPU machine) that fails with a bare network error. The real failure of
    `sapien.physx.enable_gpu()` (in a child whose home is empty) must become a line that names the file, the folder
    and the download."""
    script = textwrap.dedent("""
        import sapien.physx
        from simreel.sim.make import EnvConfig, _build_error
        try:
            sapien.physx.enable_gpu()
        except Exception as exc:
            print(_build_error("PickCube-v1", exc, backend="none", cfg=EnvConfig(num_envs=4)))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "HOME": str(tmp_path)})
    folder = next((tmp_path / ".sapien" / "physx").iterdir())
    if (folder / "libPhysXGpu_64.so").is_file():
        pytest.skip("this machine reached GitHub and SAPIEN fetched its PhysX GPU library")
    line = done.stdout.strip().splitlines()[-1]
    assert line.startswith(f"PickCube-v1: the GPU sim needs SAPIEN's PhysX GPU library, which is not in {folder}")
    assert f"/releases/download/{folder.name}/linux" in line and f"unzip it into {folder} on this one" in line


@pytest.mark.parametrize("backend", ["foo", "physx_cuda:x", "", 5])
def test_a_sim_backend_maniskill_has_no_name_for_is_named_with_those_it_has(backend):
    """Regression: ManiSkill failed on it inside gym.make as a bare KeyError ('could not build the env: KeyError:
    'foo''), naming none of its backends."""
    from simreel.errors import EnvBuildError
    from simreel.sim.make import make_env

    with pytest.raises(EnvBuildError, match=rf"^PickCube-v1: sim backend {backend!r} is none of ManiSkill's: auto, "
                                            r"physx_cpu, cpu, physx_cuda, gpu, cuda \(a CUDA device as physx_cuda:N\)$"):
        make_env("PickCube-v1", sim_backend=backend)
