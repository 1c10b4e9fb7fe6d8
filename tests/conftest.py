"""Shared fixtures: environments for subprocesses that render with lavapipe, or that have no render device.

Vulkan variables must be set before sapien loads, so tests of either render mode run their env code in a
subprocess started with one of these environments (see tests/test_envs.py).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

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


@pytest.fixture(scope="session")
def lavapipe_env() -> dict[str, str]:
    """os.environ for a subprocess where simreel finds lavapipe through SIMREEL_VK_ICD; skips if not fetched."""
    icd = _lavapipe_icd()
    if icd is None:
        pytest.skip("lavapipe not fetched: run `make setup` (or tools/fetch_lavapipe.sh .cache/mesa)")
    return {**_clean_env(), "SIMREEL_VK_ICD": str(icd)}


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
