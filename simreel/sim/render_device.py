"""Find the render device ManiSkill should use: an NVIDIA GPU, the software Vulkan (lavapipe) or none.

Two steps, both cheap and both run by `simreel.sim.make.make_env`:

1. `configure_vulkan()` points the Vulkan loader at the project-local lavapipe that `make setup` unpacks into
   ``<venv>/share/simreel/mesa`` (see ``tools/fetch_lavapipe.sh``), when the machine has no NVIDIA GPU and the
   user has not chosen a Vulkan driver. It only sets an environment variable, so it must run before sapien
   creates its Vulkan instance (safest: before sapien is imported).
2. `detect_render_backend()` asks SAPIEN which device it would render with and returns the ManiSkill
   ``render_backend`` string: ``"gpu"`` (a CUDA-capable device, e.g. NVIDIA), ``"cpu"`` (any other device
   SAPIEN accepts, e.g. lavapipe) or ``"none"`` (no device: state-only, see `simreel.sim.norender`).

The probe runs in a child process. Creating a Vulkan instance can segfault on a broken driver install
(haosulab/SAPIEN#229, inside ``sapien.Device``); in a child that costs a wrong answer, not the user's process.
When the child crashes or hangs, this process hides every Vulkan driver (``VK_ICD_FILENAMES`` set to a path
that does not exist) so ManiSkill's own ``sapien.Device("cpu")`` call cannot crash either, and the env runs
state-only. The child costs ~0.3 s (mostly ``import sapien``); `start_render_probe` starts it early so that
it overlaps with importing mani_skill.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

__all__ = [
    "RenderBackend",
    "RenderDevice",
    "RenderProbe",
    "configure_vulkan",
    "device_expected",
    "lavapipe_icd_path",
    "start_render_probe",
    "probe_render_device",
    "detect_render_backend",
    "parse_device_summary",
    "choose_backend",
]

RenderBackend = Literal["gpu", "cpu", "none"]

PROBE_TIMEOUT_S = 60.0
"""A probe that takes longer is treated as a hung driver: no render device."""

_NVIDIA_MARKERS = ("/dev/nvidia0", "/proc/driver/nvidia")
_HIDDEN_ICD = "/nonexistent/simreel-vulkan-hidden.json"
"""What `VK_ICD_FILENAMES` is set to after a crashed probe: a path that cannot exist, so the loader finds no driver."""

# Runs in the child. Prints exactly one JSON line; a crash shows as a negative return code.
_PROBE_SCRIPT = """
import sys
sys.path[:] = [p for p in sys.path if p]  # not the user's folder (`-c` puts it first): a sapien.py there is not SAPIEN
import json, time, warnings
warnings.simplefilter("ignore")
try:
    import sapien
    answer = {"summary": sapien.render.get_device_summary()}
except Exception as exc:
    answer = {"error": f"{type(exc).__name__}: {exc}"}
answer["finished_at"] = time.time()
print(json.dumps(answer))
"""


def lavapipe_icd_path() -> Path:
    """Where simreel looks for the lavapipe ICD json: ``$SIMREEL_VK_ICD``, else ``<venv>/share/simreel/mesa/lvp_icd.json``."""
    override = os.environ.get("SIMREEL_VK_ICD")
    if override:
        return Path(override)
    return Path(sys.prefix) / "share" / "simreel" / "mesa" / "lvp_icd.json"


def has_nvidia_gpu() -> bool:
    """An NVIDIA GPU and driver are present (its device node or /proc entry exists), working Vulkan or not."""
    return any(os.path.exists(marker) for marker in _NVIDIA_MARKERS)


def device_expected() -> bool:
    """Cheap guess, without a probe: an NVIDIA GPU is present, or `configure_vulkan` pointed Vulkan at the
    lavapipe that `make setup` fetched. False means only a probe can tell."""
    icd = lavapipe_icd_path()
    configured = os.environ.get("VK_ICD_FILENAMES") == os.path.abspath(icd) and icd.is_file()
    return has_nvidia_gpu() or configured


def configure_vulkan() -> str | None:
    """Point Vulkan at the project-local lavapipe when nothing better is there; return the ICD path set, or None.

    Sets ``VK_ICD_FILENAMES`` only if all hold: neither ``VK_ICD_FILENAMES`` nor ``VK_DRIVER_FILES`` is set
    (the user's choice wins), there is no NVIDIA GPU (``/dev/nvidia0`` and ``/proc/driver/nvidia`` absent), and
    `lavapipe_icd_path()` exists. Idempotent. Never sets ``SAPIEN_DISABLE_RAY_TRACING``: SAPIEN picks lavapipe
    only because it advertises ray tracing.

    Call it before sapien is imported. (Measured with sapien 3.0.3: the loader reads the variable when SAPIEN
    first creates its Vulkan instance, which importing mani_skill does not do, but that is not a promise.)
    """
    if os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES"):
        return None
    if has_nvidia_gpu():
        return None
    icd = lavapipe_icd_path()
    if not icd.is_file():
        return None
    os.environ["VK_ICD_FILENAMES"] = os.path.abspath(icd)
    return os.environ["VK_ICD_FILENAMES"]


@dataclass(frozen=True)
class RenderDevice:
    """One Vulkan device as SAPIEN reports it."""

    name: str
    supported: bool
    """SAPIEN accepts it for rendering (queues and features it needs are there)."""
    cuda_id: int
    """CUDA ordinal SAPIEN paired it with, -1 if none."""


@dataclass(frozen=True)
class RenderProbe:
    """The answer of one probe: which backend to use, on what, and why."""

    backend: RenderBackend
    devices: tuple[RenderDevice, ...] = ()
    detail: str = ""
    """Why this backend: the device used, or the reason there is none."""
    vulkan_icd: str | None = None
    """``VK_ICD_FILENAMES`` (or ``VK_DRIVER_FILES``) as the probe saw it."""
    seconds: float = 0.0
    """Wall time of the probe itself, from starting the child to its answer (not time spent waiting for it)."""
    env_overrides: dict[str, str] = field(default_factory=dict)
    """Environment variables this process set because of the probe (hiding Vulkan after a crash)."""


def parse_device_summary(summary: str) -> tuple[RenderDevice, ...]:
    """Parse ``sapien.render.get_device_summary()`` (sapien 3.0.x) into devices.

    The text is one block per device::

        GPU: llvmpipe (LLVM 15.0.6, 256 bits)
          Supported: 1
          Present:   0
          cudaId:    -1
          rayTrace:  1
          cudaMode   -1
    """
    devices = []
    for block in re.split(r"^(?=\S)", summary, flags=re.MULTILINE):
        head, _, rest = block.partition("\n")
        if ":" not in head:
            continue
        name = head.split(":", 1)[1].strip()
        fields = dict(re.findall(r"^\s+(\w+):?\s+(-?\d+)\s*$", rest, flags=re.MULTILINE))
        devices.append(
            RenderDevice(
                name=name,
                supported=fields.get("Supported") == "1",
                cuda_id=int(fields.get("cudaId", "-1")),
            )
        )
    return tuple(devices)


def choose_backend(devices: tuple[RenderDevice, ...]) -> tuple[RenderBackend, str]:
    """The backend for these devices and why: CUDA-paired and supported → gpu; supported → cpu; else none."""
    supported = [d for d in devices if d.supported]
    cuda = [d for d in supported if d.cuda_id >= 0]
    if cuda:
        return "gpu", f"{cuda[0].name} (cuda:{cuda[0].cuda_id})"
    if supported:
        return "cpu", supported[0].name
    if devices:
        names = ", ".join(d.name for d in devices)
        return "none", f"Vulkan devices found but none SAPIEN can render with: {names}"
    return "none", "no Vulkan device"


_lock = threading.Lock()
_pending: tuple[subprocess.Popen[str], float, float, str | None] | None = None
_cached: RenderProbe | None = None


def _current_icd() -> str | None:
    return os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES") or None


def start_render_probe() -> None:
    """Start the probe in the background (after `configure_vulkan`); `probe_render_device` collects it.

    Does nothing if a probe already ran or is running in this process.
    """
    with _lock:
        _start_locked()


def _start_locked() -> None:
    global _pending
    if _cached is not None or _pending is not None:
        return
    configure_vulkan()
    child = subprocess.Popen(
        [sys.executable, "-c", _PROBE_SCRIPT],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _pending = (child, time.perf_counter(), time.time(), _current_icd())


def _hide_vulkan(reason: str) -> dict[str, str]:
    os.environ["VK_ICD_FILENAMES"] = _HIDDEN_ICD
    os.environ.pop("VK_DRIVER_FILES", None)
    warnings.warn(
        f"simreel: {reason}; Vulkan is now hidden from this process (VK_ICD_FILENAMES={_HIDDEN_ICD}) and envs "
        "run state-only. Check the GPU driver / Vulkan install (`vulkaninfo`), or set VK_ICD_FILENAMES yourself.",
        RuntimeWarning,
        stacklevel=3,
    )
    return {"VK_ICD_FILENAMES": _HIDDEN_ICD}


def _collect(child: subprocess.Popen[str], started: float, started_wall: float, icd: str | None) -> RenderProbe:
    try:
        out, err = child.communicate(timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        child.kill()
        child.communicate()
        reason = f"the Vulkan device probe hung for {PROBE_TIMEOUT_S:.0f} s"
        return RenderProbe("none", detail=reason, vulkan_icd=icd, seconds=time.perf_counter() - started,
                           env_overrides=_hide_vulkan(reason))
    seconds = time.perf_counter() - started
    if child.returncode != 0:
        how = f"signal {-child.returncode}" if child.returncode < 0 else f"exit status {child.returncode}"
        last = err.strip().splitlines()[-1:] or [""]
        reason = f"the Vulkan device probe crashed ({how}) {last[0]}".strip()
        return RenderProbe("none", detail=reason, vulkan_icd=icd, seconds=seconds,
                           env_overrides=_hide_vulkan(reason))
    try:
        answer = json.loads(out.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return RenderProbe("none", detail=f"unreadable probe output: {out[-200:]!r}", vulkan_icd=icd, seconds=seconds)
    if isinstance(answer.get("finished_at"), float):
        seconds = min(seconds, max(0.0, answer["finished_at"] - started_wall))
    if "error" in answer:
        error = answer["error"]
        if error == "RuntimeError: failed to find a rendering device":
            error = "no Vulkan device SAPIEN can render with"
        return RenderProbe("none", detail=error, vulkan_icd=icd, seconds=seconds)
    devices = parse_device_summary(answer["summary"])
    backend, detail = choose_backend(devices)
    return RenderProbe(backend, devices=devices, detail=detail, vulkan_icd=icd, seconds=seconds)


def probe_render_device() -> RenderProbe:
    """The probe's full answer, cached for the life of the process (starts the probe if nobody did)."""
    global _pending, _cached
    with _lock:
        if _cached is None:
            _start_locked()
            if _pending is not None:
                child, started, started_wall, icd = _pending
                _pending = None
                _cached = _collect(child, started, started_wall, icd)
        return _cached


def detect_render_backend() -> RenderBackend:
    """The ManiSkill ``render_backend`` to use here: ``"gpu"``, ``"cpu"`` or ``"none"``; cached per process.

    ``"gpu"``: SAPIEN found a device it can render with that is paired with CUDA (NVIDIA).
    ``"cpu"``: a device it can render with but no CUDA (lavapipe/llvmpipe; ManiSkill's ``sapien_cpu``).
    ``"none"``: no usable device; only state observations work (see `simreel.sim.norender`).
    """
    return probe_render_device().backend
