"""simreel.sim.render_device: Vulkan set-up and the render-device probe, with lavapipe, with no device, with a crash."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from simreel.sim.render_device import RenderDevice, choose_backend, configure_vulkan, parse_device_summary

LAVAPIPE_SUMMARY = (
    "GPU: llvmpipe (LLVM 15.0.6, 256 bits)\n  Supported: 1\n  Present:   0\n  cudaId:    -1\n"
    "  rayTrace:  1\n  cudaMode   -1\n"
)
NVIDIA_AND_LAVAPIPE_SUMMARY = (
    "GPU: NVIDIA H100 80GB HBM3\n  Supported: 1\n  Present:   0\n  cudaId:    0\n  rayTrace:  1\n  cudaMode   1\n"
    + LAVAPIPE_SUMMARY
)
HAS_NVIDIA = os.path.exists("/dev/nvidia0") or os.path.exists("/proc/driver/nvidia")

# Prints the probe as JSON, then proves this process can still touch Vulkan without crashing.
PROBE_SCRIPT = textwrap.dedent(
    """
    import dataclasses, json, warnings
    from simreel.sim import render_device
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        probe = render_device.probe_render_device()
    same = render_device.probe_render_device() is probe and render_device.detect_render_backend() == probe.backend
    import sapien
    sapien.Device("cpu")  # what ManiSkill calls for every env, render device or not
    print(json.dumps({**dataclasses.asdict(probe), "cached": same, "warnings": [str(w.message) for w in caught]}))
    """
)


def run_probe(env: dict[str, str], cwd: Path | None = None) -> dict:
    """The probe's answer in a fresh process (its folder `cwd` kept off its module path, as a console script's is)."""
    script = "import sys; sys.path[:] = [p for p in sys.path if p]\n" + PROBE_SCRIPT
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120,
                          cwd=cwd)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_parse_device_summary_lavapipe():
    assert parse_device_summary(LAVAPIPE_SUMMARY) == (
        RenderDevice(name="llvmpipe (LLVM 15.0.6, 256 bits)", supported=True, cuda_id=-1),
    )
    assert choose_backend(parse_device_summary(LAVAPIPE_SUMMARY)) == ("cpu", "llvmpipe (LLVM 15.0.6, 256 bits)")


def test_cuda_device_wins_over_lavapipe():
    devices = parse_device_summary(NVIDIA_AND_LAVAPIPE_SUMMARY)
    assert [d.cuda_id for d in devices] == [0, -1]
    assert choose_backend(devices) == ("gpu", "NVIDIA H100 80GB HBM3 (cuda:0)")


@pytest.mark.parametrize(
    ("summary", "detail"),
    [
        ("", "no Vulkan device"),
        (LAVAPIPE_SUMMARY.replace("Supported: 1", "Supported: 0"),
         "Vulkan devices found but none SAPIEN can render with: llvmpipe (LLVM 15.0.6, 256 bits)"),
    ],
)
def test_no_supported_device_means_none(summary, detail):
    assert choose_backend(parse_device_summary(summary)) == ("none", detail)


@pytest.mark.skipif(HAS_NVIDIA, reason="configure_vulkan leaves NVIDIA machines alone")
class TestConfigureVulkan:
    @pytest.fixture(autouse=True)
    def _clean(self, monkeypatch):
        for var in ("VK_ICD_FILENAMES", "VK_DRIVER_FILES", "SIMREEL_VK_ICD"):
            monkeypatch.delenv(var, raising=False)

    def test_points_vulkan_at_the_project_lavapipe(self, monkeypatch, tmp_path):
        icd = tmp_path / "lvp_icd.json"
        icd.write_text("{}")
        monkeypatch.chdir(tmp_path)
        monkeypatch.setenv("SIMREEL_VK_ICD", "lvp_icd.json")  # relative: made absolute
        assert configure_vulkan() == str(icd)
        assert os.environ["VK_ICD_FILENAMES"] == str(icd)
        assert configure_vulkan() is None  # idempotent: now the variable is set
        assert "SAPIEN_DISABLE_RAY_TRACING" not in os.environ

    @pytest.mark.parametrize("var", ["VK_ICD_FILENAMES", "VK_DRIVER_FILES"])
    def test_user_choice_wins(self, monkeypatch, tmp_path, var):
        icd = tmp_path / "lvp_icd.json"
        icd.write_text("{}")
        monkeypatch.setenv("SIMREEL_VK_ICD", str(icd))
        monkeypatch.setenv(var, "/users/own_icd.json")
        assert configure_vulkan() is None
        assert os.environ[var] == "/users/own_icd.json"

    def test_missing_lavapipe_sets_nothing(self, monkeypatch, tmp_path):
        monkeypatch.setenv("SIMREEL_VK_ICD", str(tmp_path / "missing.json"))
        assert configure_vulkan() is None
        assert "VK_ICD_FILENAMES" not in os.environ


def test_probe_with_lavapipe_says_cpu(lavapipe_env):
    probe = run_probe(lavapipe_env)
    assert probe["backend"] == "cpu"
    assert "llvmpipe" in probe["detail"]
    assert probe["vulkan_icd"] == lavapipe_env["SIMREEL_VK_ICD"]
    assert probe["cached"] is True
    assert probe["env_overrides"] == {} and probe["warnings"] == []


def test_a_sapien_module_in_the_users_folder_does_not_fool_the_probe(lavapipe_env, tmp_path):
    """Regression: the probe's child (`python -c`) imported the user's own sapien.py from the folder simreel ran in."""
    (tmp_path / "sapien.py").write_text("raise ImportError('the user project, not SAPIEN')\n")
    assert run_probe(lavapipe_env, cwd=tmp_path)["backend"] == "cpu"


def test_probe_without_any_device_says_none(no_render_env):
    probe = run_probe(no_render_env)
    assert probe["backend"] == "none"
    assert probe["detail"] == "no Vulkan device SAPIEN can render with"
    assert probe["devices"] == []
    assert probe["env_overrides"] == {} and probe["warnings"] == []


CRASHING_ICD = """
#include <signal.h>
void *vk_icdGetInstanceProcAddr(void *instance, const char *name) { raise(SIGSEGV); return 0; }
int vk_icdNegotiateLoaderICDInterfaceVersion(unsigned *version) { raise(SIGSEGV); return 0; }
"""


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler to build a crashing Vulkan driver")
def test_crashing_driver_is_probed_safely_and_hidden(no_render_env, tmp_path: Path):
    """A Vulkan driver that segfaults (haosulab/SAPIEN#229) kills the probe child, not the caller."""
    (tmp_path / "crash.c").write_text(CRASHING_ICD)
    subprocess.run(["cc", "-shared", "-fPIC", "-o", str(tmp_path / "libcrash.so"), str(tmp_path / "crash.c")],
                   check=True)
    icd = tmp_path / "crash_icd.json"
    icd.write_text(json.dumps({"file_format_version": "1.0.0",
                               "ICD": {"library_path": str(tmp_path / "libcrash.so"), "api_version": "1.3.0"}}))
    env = {**no_render_env, "VK_ICD_FILENAMES": str(icd)}
    crashed = subprocess.run([sys.executable, "-c", "import sapien; sapien.Device('cpu')"], env=env,
                             capture_output=True, timeout=120)
    assert crashed.returncode == -11  # the hazard itself: plain sapien dies

    probe = run_probe(env)  # survives, and its own sapien.Device("cpu") call afterwards too
    assert probe["backend"] == "none"
    assert probe["detail"] == "the Vulkan device probe crashed (signal 11)"
    assert probe["vulkan_icd"] == str(icd)
    assert probe["env_overrides"] == {"VK_ICD_FILENAMES": "/nonexistent/simreel-vulkan-hidden.json"}
    assert len(probe["warnings"]) == 1 and "Vulkan is now hidden from this process" in probe["warnings"][0]
