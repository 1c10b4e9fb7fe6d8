"""Shared fixtures: environments for subprocesses that render with lavapipe or have no render device, real
recordings made once per session, and the viewer tests' recording and .rrd reader.

Vulkan variables must be set before sapien loads, so tests of either render mode run their env code in a
subprocess started with one of these environments (see tests/sim/test_make.py).
"""

from __future__ import annotations

import gc
import os
import signal
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from support.rrd import read_rrd
from support.viewer_data import record_pickcube, write_variant

from simreel.cli.main import main
from simreel.sim.render_device import configure_vulkan

# The project lavapipe for the envs tests build in this process (ManiSkill's own tools, a plain gym.make), as a
# user's script gets it from `prepare_plain_gym_make()`; `import simreel` itself changes no environment variable.
configure_vulkan()

# The Ctrl-C tests stand for a user at a terminal. A suite started in the background by a non-interactive
# shell (`make test &`, some CI runners) inherits SIGINT ignored, and so would every process it starts; Python
# then never raises KeyboardInterrupt. Give this process, and through exec its children, the terminal's default.
signal.signal(signal.SIGINT, signal.default_int_handler)

REPO = Path(__file__).resolve().parents[1]
_VULKAN_VARS = ("VK_ICD_FILENAMES", "VK_DRIVER_FILES", "VK_ADD_DRIVER_FILES", "SIMREEL_VK_ICD")
_SYSTEM_VULKAN = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/dev/nvidia0", "/proc/driver/nvidia")


def _lavapipe_icd() -> Path | None:
    """$SIMREEL_VK_ICD, else where `make setup` puts it, else the repo's .cache/mesa (tools/fetch_lavapipe.sh)."""
    candidates = [
        os.environ.get("SIMREEL_VK_ICD"),
        Path(sys.prefix) / "share" / "simreel" / "mesa" / "lvp_icd.json",
        REPO / ".cache" / "mesa" / "lvp_icd.json",
    ]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return Path(candidate).resolve()
    return None


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in _VULKAN_VARS}


@pytest.fixture(scope="module", autouse=True)
def _frozen_heap():
    """Each module starts with the objects already alive frozen out of the garbage collector's sight.

    ManiSkill calls `gc.collect()` whenever it builds a scene (each env built, each reset that reconfigures, each
    close). A full collection walks every object the process tracks, and a test process holds some 300,000 from
    torch, sapien and mani_skill alone: 0.2-0.3 s a collection, most of an in-process env build or replayed
    episode. Frozen objects are still freed when their last reference goes; only the cycle collector skips them.
    The collection first means no garbage of an earlier module is frozen.
    """
    gc.collect()
    gc.freeze()


@pytest.fixture(scope="session")
def lavapipe_env() -> dict[str, str]:
    """os.environ for a subprocess where simreel finds lavapipe through SIMREEL_VK_ICD; skips if not fetched."""
    icd = _lavapipe_icd()
    if icd is None:
        pytest.skip("lavapipe not fetched: run `make setup` (or tools/fetch_lavapipe.sh .cache/mesa)")
    return {**_clean_env(), "SIMREEL_VK_ICD": str(icd)}


@pytest.fixture(scope="session")
def maniskill_env(lavapipe_env) -> dict[str, str]:
    """os.environ for ManiSkill's own tools (replay_trajectory) on this machine: they do not import simreel, so
    the lavapipe driver is named to the Vulkan loader directly, as the README tells users to."""
    return {**lavapipe_env, "VK_ICD_FILENAMES": lavapipe_env["SIMREEL_VK_ICD"]}


@pytest.fixture(scope="session")
def no_render_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """os.environ for a subprocess with no render device: VK_ICD_FILENAMES unset, SIMREEL_VK_ICD missing.

    Where the machine has a system Vulkan driver or an NVIDIA GPU, VK_ICD_FILENAMES is set to a missing file
    as well, so the subprocess still sees no device.
    """
    env = {**_clean_env(), "SIMREEL_VK_ICD": str(tmp_path_factory.mktemp("no-vulkan") / "missing_icd.json")}
    if any(os.path.exists(p) for p in _SYSTEM_VULKAN):
        env["VK_ICD_FILENAMES"] = env["SIMREEL_VK_ICD"]
    return env


@pytest.fixture(scope="session")
def record(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """`record(env_id, n=2, steps=20, *extra_args)` → path of a fresh recording (cached per argument list), made
    in-process and state-only (no render device needed)."""
    cache: dict[tuple, Path] = {}
    folder = tmp_path_factory.mktemp("recordings")

    def _record(env_id: str, n: int = 2, steps: int = 20, *extra: str) -> Path:
        key = (env_id, n, steps, *extra)
        if key not in cache:
            out = folder / f"{len(cache):02d}_{env_id}.h5"
            args = ["record", env_id, "-o", str(out), "-n", str(n), "--max-steps", str(steps), "--seed", "3",
                    "--render-backend", "none", "-q", *extra]
            if env_id.startswith("Simreel"):
                args += ["--policy", "scripted", "--import", "simreel.tasks"]
            assert main(args) == 0
            cache[key] = out
        return cache[key]

    return _record


@pytest.fixture(scope="session")
def rrd_reader():
    return read_rrd


@pytest.fixture(scope="session")
def variant():
    """`variant(src, dst, shift_from=, drop_poses=, camera=)`: see `support.viewer_data.write_variant`."""
    return write_variant


@pytest.fixture(scope="session")
def pickcube_h5(tmp_path_factory) -> Path:
    """30 steps of PickCube-v1 with body poses recorded (see `support.viewer_data.record_pickcube`)."""
    path = tmp_path_factory.mktemp("rec") / "pickcube.h5"
    record_pickcube(path, poses=True)
    return path


@pytest.fixture(scope="session")
def view_env(pickcube_h5):
    """One PickCube env rebuilt for viewing (collision geometry, no rendering), shared by the tests."""
    from simreel.formats import open_reader
    from simreel.viewers import rebuild_env

    with open_reader(pickcube_h5) as r:
        env = rebuild_env(r.meta, geometry="collision")
    yield env
    env.close()
