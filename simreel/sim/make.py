"""Build ManiSkill envs the same way everywhere in simreel, on a GPU, on lavapipe or with no render device.

`make_env` is the only place simreel calls ``gym.make``. It configures Vulkan before sapien loads, picks the
render backend, switches on the no-render layer when there is no device, and turns every failure into a
`simreel.errors.SimreelError` whose one line says what went wrong and how to fix it. `EnvConfig` is the one
list of ``gym.make`` arguments simreel names: `make_env` takes them and a recording's metadata keeps them.
mani_skill (~3 s to import) is imported inside the functions here, never at module level.
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import os
import traceback
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from simreel.errors import EnvBuildError, RenderUnavailableError
from simreel.model.env_config import EnvConfig
from simreel.sim.modes import check_modes, control_mode_error
from simreel.sim.render_device import (
    configure_vulkan,
    device_expected,
    probe_render_device,
    start_render_probe,
)
from simreel.sim.upstream_noise import quiet_upstream_noise
from simreel.sim.user_code import import_mani_skill, native_import, task_code_error

if TYPE_CHECKING:
    import gymnasium as gym


__all__ = [
    "EnvConfig",
    "make_env",
    "prepare_plain_gym_make",
    "time_limit",
    "env_versions",
    "camera_use",
    "CAMERA_TEXTURES",
    "SIMREEL_TASK_PREFIX",
    "no_render_device_fix",
    "render_fix",
]

CAMERA_TEXTURES = frozenset(
    {"rgb", "depth", "rgbd", "pointcloud", "sensor_data", "segmentation", "position", "normal", "albedo"}
)
"""Parts of an ``obs_mode`` (split on ``+``) that need cameras, hence a render device."""

SIMREEL_TASK_PREFIX = "Simreel"
"""Env ids of simreel's own example tasks; `make_env` registers them on first use, no --import needed."""

_VERSIONED_DISTRIBUTIONS = {
    "simreel": "simreel",
    "mani_skill": "mani-skill",
    "sapien": "sapien",
    "torch": "torch",
    "numpy": "numpy",
    "gymnasium": "gymnasium",
}


def _fold_env_kwargs(env_id: str, cfg: EnvConfig) -> EnvConfig:
    """`cfg` with the named arguments its `env_kwargs` also hold (``--env-kwargs '{"sim_config": {...}}'``) moved
    into their own fields; `EnvBuildError` where both give one, differently (a field at its default gives none)."""
    repeated = sorted(set(cfg.env_kwargs) & set(EnvConfig.names()) - {"env_kwargs"})
    if not repeated:
        return cfg
    default = EnvConfig()
    refuse_repeated(env_id, {name: getattr(cfg, name) for name in repeated
                             if getattr(cfg, name) != getattr(default, name)}, cfg.env_kwargs)
    kwargs = dict(cfg.env_kwargs)
    return dataclasses.replace(cfg, env_kwargs=kwargs, **{name: kwargs.pop(name) for name in repeated})


def refuse_repeated(env_id: str, given: Mapping[str, Any], env_kwargs: Mapping[str, Any]) -> None:
    """`EnvBuildError` where an argument `given` by its name (an `EnvConfig` field, a CLI option) is also in
    `env_kwargs` with another value: the env would be built with one of the two without a word."""
    for name in sorted(set(given) & set(env_kwargs)):
        if given[name] != env_kwargs[name]:
            raise EnvBuildError(f"{env_id}: {name} is given twice, {given[name]!r} and {env_kwargs[name]!r} in "
                                "env_kwargs (--env-kwargs); give it once")


def camera_use(obs_mode: str | None, render_mode: str | None = None) -> str | None:
    """Say why this ``obs_mode`` / ``render_mode`` needs a render device, or None if it does not."""
    if obs_mode:
        textures = sorted(set(obs_mode.split("+")) & CAMERA_TEXTURES)
        if textures:
            return f"obs_mode={obs_mode!r} needs camera images ({', '.join(textures)})"
    if render_mode is not None:
        return f"render_mode={render_mode!r} renders images"
    return None


def make_env(env_id: str, config: EnvConfig | None = None, **overrides: Any) -> gym.Env:
    """Build a registered ManiSkill env with ``gym.make`` and return it.

    `config` (default `EnvConfig()`) with `overrides` applied, e.g. ``make_env("PickCube-v1", obs_mode="rgb")``;
    see `EnvConfig` for every argument. Custom tasks must be registered first (`simreel.sim.user_code.import_user_code`);
    simreel's own example tasks (``Simreel*``) register themselves.

    Raises:
        EnvBuildError: unknown env id (with close matches), missing assets, bad kwargs (ManiSkill's own message).
        RenderUnavailableError: cameras or ``render_mode`` were asked for but there is no render device, or the
            task cannot be built without one (PushT-v1).
    """
    cfg = _fold_env_kwargs(env_id, (config or EnvConfig()).with_overrides(**overrides))
    _check_sim_backend(env_id, cfg.sim_backend)
    configure_vulkan()
    if cfg.render_backend == "auto":
        start_render_probe()  # runs in a child process while mani_skill imports here
    gym = _registered(env_id)
    _check_modes(env_id, cfg)
    backend = _prepare_render(env_id, cfg)
    kwargs = _gym_kwargs(cfg, backend)
    try:
        with _maniskill_log_held():
            return gym.make(env_id, **kwargs)
    except SystemExit as exc:  # ManiSkill calls exit() when asked for assets it cannot get
        raise EnvBuildError(f"{env_id}: ManiSkill exited while building the env ({exc.code})") from exc
    except Exception as exc:
        raise _build_error(env_id, exc, backend=backend, cfg=cfg) from exc


@contextlib.contextmanager
def _maniskill_log_held() -> Iterator[None]:
    """ManiSkill's log lines while it builds an env, held: written once the env is built, dropped when the build
    fails, whose one line says what went wrong (ManiSkill's WARNING of an unknown robot, then its error, would be
    two)."""
    import logging

    from mani_skill import logger

    held: list[logging.LogRecord] = []

    class _Hold(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            held.append(record)

    handlers, logger.handlers = logger.handlers, [_Hold()]
    try:
        yield
    finally:
        logger.handlers = handlers
    for record in held:  # only when the block ended well
        logger.handle(record)


SIM_BACKENDS = ("auto", "physx_cpu", "cpu", "physx_cuda", "gpu", "cuda")
"""The sim backends ManiSkill 3.0.1 takes (`parse_sim_and_render_backend`), a CUDA one also as ``physx_cuda:N``."""


def _check_sim_backend(env_id: str, sim_backend: Any) -> None:
    """`EnvBuildError` naming the sim backends there are for one ManiSkill has no name for: it fails on it inside
    gym.make as a bare KeyError ('foo')."""
    name, _, device = sim_backend.partition(":") if isinstance(sim_backend, str) else (None, "", "")
    if name not in SIM_BACKENDS or (device and not device.isdigit()):
        raise EnvBuildError(f"{env_id}: sim backend {sim_backend!r} is none of ManiSkill's: {', '.join(SIM_BACKENDS)} "
                            "(a CUDA device as physx_cuda:N)")


def _check_modes(env_id: str, cfg: EnvConfig) -> None:
    from mani_skill.utils.registration import REGISTERED_ENVS

    check_modes(env_id, REGISTERED_ENVS[env_id].cls, cfg.obs_mode, cfg.control_mode, cfg.env_kwargs)


def time_limit(env_id: str) -> int | None:
    """The time limit (``max_episode_steps``) `env_id` is registered with, None when it has none; raises
    `EnvBuildError` for an unknown id. Custom tasks must be registered first, as for `make_env`."""
    _registered(env_id)
    from mani_skill.utils.registration import REGISTERED_ENVS

    return REGISTERED_ENVS[env_id].max_episode_steps


def reward_modes(env_id: str) -> tuple[str, ...]:
    """The reward modes `env_id`'s class supports (``SUPPORTED_REWARD_MODES``); raises `EnvBuildError` for an
    unknown id, as `time_limit` does."""
    _registered(env_id)
    from mani_skill.utils.registration import REGISTERED_ENVS

    return tuple(getattr(REGISTERED_ENVS[env_id].cls, "SUPPORTED_REWARD_MODES", ()))


def prepare_plain_gym_make() -> None:
    """Let the user's own ``gym.make`` (not `make_env`) build ManiSkill envs on this machine.

    Points Vulkan at the software driver `make setup` fetched (`configure_vulkan`); where no render device is
    expected (no NVIDIA GPU, no fetched driver) it asks the probe (a child process, ~0.3 s), and when there is
    no device installs the no-render layer, so ``gym.make(env_id, obs_mode="state", render_backend="none")``
    builds (ManiSkill itself needs ``render_backend="none"`` there). Known upstream messages that ask nothing of
    the user are hidden from then on (`simreel.sim.upstream_noise`). Call it before ``gym.make`` (and before
    importing mani_skill or sapien, for SAPIEN's libvulkan warning); importing `simreel.recorders.RecordWrapper` does.
    """
    quiet_upstream_noise()
    configure_vulkan()
    if device_expected() or probe_render_device().backend != "none":
        return
    from simreel.sim import norender

    with native_import():
        norender.install()


def _registered(env_id: str) -> Any:
    """Import mani_skill (registering its tasks; simreel's too for a ``Simreel*`` id), check `env_id` is known
    and its assets are there; return gymnasium."""
    import gymnasium

    import_mani_skill()
    from mani_skill.utils.registration import REGISTERED_ENVS

    spec = REGISTERED_ENVS.get(env_id)
    if spec is None and env_id.startswith(SIMREEL_TASK_PREFIX):
        import simreel.tasks  # noqa: F401  (simreel's example tasks register on import)

        spec = REGISTERED_ENVS.get(env_id)
    if spec is None:
        raise EnvBuildError(_unknown_env_message(env_id, REGISTERED_ENVS))
    missing = _missing_assets(spec)
    if missing:
        raise EnvBuildError(
            f"{env_id} needs assets that are not downloaded: {' '.join(missing)}. Fetch them with "
            f"`python -m mani_skill.utils.download_asset {missing[0]}` (needs internet; MS_ASSET_DIR sets where)"
        )
    return gymnasium


def _unknown_env_message(env_id: str, registry: dict[str, Any]) -> str:
    """Close matches of `env_id`, and what to do: import the task, or, when user code was imported, what that
    code registers (it did not register `env_id`)."""
    from simreel.sim.user_code import imported_user_code

    by_lower = {name.lower(): name for name in registry}
    close = difflib.get_close_matches(env_id.lower(), list(by_lower), n=3, cutoff=0.6)
    hint = f"did you mean {', '.join(by_lower[c] for c in close)}?" if close else f"{len(registry)} are registered"
    imported = imported_user_code()
    if not imported:
        return (f"unknown ManiSkill env id {env_id!r}: {hint} "
                "(a custom task must be registered first: pass --import MODULE_OR_FILE.py)")
    registered = []
    for spec, module in imported.items():
        ids = [uid for uid, s in registry.items() if _defined_in(s, module)]
        registered.append(f"{spec} registers {', '.join(ids) if ids else 'no env'}")
    return f"unknown ManiSkill env id {env_id!r}: {hint} (the code imported does not register it: {'; '.join(registered)})"


def _defined_in(spec: Any, module: str) -> bool:
    """Whether the task class of a registry entry comes from `module` or one of its submodules."""
    where = getattr(getattr(spec, "cls", None), "__module__", "") or ""
    return where == module or where.startswith(module + ".")


def _missing_assets(spec: Any) -> list[str]:
    """Asset ids a registered task needs that are not downloaded (ManiSkill would prompt on stdin, then exit)."""
    from mani_skill.utils import assets

    missing: list[str] = []
    for asset_id in spec.asset_download_ids or []:
        if asset_id in assets.DATA_GROUPS:
            ids = assets.expand_data_group_into_individual_data_source_ids(asset_id)
        else:
            ids = [asset_id]
        missing += [i for i in ids if i in assets.DATA_SOURCES and not assets.is_data_source_downloaded(i)]
    return missing


def _prepare_render(env_id: str, cfg: EnvConfig) -> str:
    """The ManiSkill render backend to build with; without a device, check that the env needs none and switch
    on the no-render layer."""
    backend, why = _resolve_render_backend(cfg.render_backend)
    if backend == "none":
        needs = camera_use(cfg.obs_mode, cfg.env_kwargs.get("render_mode"))
        if needs is not None:
            raise RenderUnavailableError(
                f"{env_id}: {needs}, but there is no render device ({why}). To render, "
                f"{render_fix(cfg.render_backend)}; or use obs_mode='state' and no render_mode."
            )
        from simreel.sim import norender

        norender.check_task(env_id)
        norender.install()
    return backend


def _resolve_render_backend(render_backend: str | None) -> tuple[str, str]:
    """Return (ManiSkill render_backend, why)."""
    if render_backend is None or render_backend == "none":
        return "none", "render_backend='none' was asked for"
    if render_backend != "auto":
        return render_backend, f"render_backend={render_backend!r} was asked for"
    probe = probe_render_device()
    return probe.backend, probe.detail


def _gym_kwargs(cfg: EnvConfig, backend: str) -> dict[str, Any]:
    kwargs: dict[str, Any] = {
        **cfg.env_kwargs,
        "num_envs": cfg.num_envs,
        "obs_mode": cfg.obs_mode,
        "control_mode": cfg.control_mode,
        "reward_mode": cfg.reward_mode,
        "sim_backend": cfg.sim_backend,
        "render_backend": backend,
    }
    if cfg.sim_config is not None:
        kwargs["sim_config"] = cfg.sim_config
    if cfg.max_episode_steps is not None:
        kwargs["max_episode_steps"] = cfg.max_episode_steps
    return kwargs


def render_fix(asked: str | None) -> str:
    """How to get the render device an env needs and did not get, as one clause of an error message: ask for one
    (render backend 'none' asks for none), fix the user's own Vulkan setting, or fetch lavapipe."""
    if asked in (None, "none"):
        return "ask for one: drop --render-backend none (render_backend='none' asks for no device)"
    from simreel.sim.render_device import lavapipe_icd_path

    ours = os.path.abspath(lavapipe_icd_path())
    for var in ("VK_DRIVER_FILES", "VK_ICD_FILENAMES"):
        value = os.environ.get(var)
        if value and value != ours:  # the user's choice, which simreel never overrides
            missing = [f for f in value.split(os.pathsep) if f and not os.path.exists(f)]
            why = f"{', '.join(missing)} does not exist" if missing else "it gives no device SAPIEN can render with"
            return f"fix or unset {var}={value} ({why}; unset, simreel uses the lavapipe `make setup` fetched)"
    return no_render_device_fix()


def no_render_device_fix() -> str:
    """How to get a render device, as one clause of an error message: fetch lavapipe the way `make setup` does
    (spelled out for a pip install, which has no Makefile), or use a GPU machine; on a machine with an NVIDIA GPU
    whose Vulkan SAPIEN cannot use (a CUDA-only container, no Vulkan loader), make that Vulkan visible, or point
    Vulkan at lavapipe by hand (`configure_vulkan` leaves an NVIDIA machine's Vulkan alone)."""
    import shlex

    from simreel.sim.render_device import has_nvidia_gpu, lavapipe_icd_path

    icd = lavapipe_icd_path()  # where simreel looks: $SIMREEL_VK_ICD, else <venv>/share/simreel/mesa/lvp_icd.json
    fetch = f"tools/fetch_lavapipe.sh {shlex.quote(str(icd.parent))}"
    if icd.name != "lvp_icd.json":  # the script writes DIR/lvp_icd.json
        fetch += f" and set SIMREEL_VK_ICD={shlex.quote(str(icd.parent / 'lvp_icd.json'))}"
    lavapipe = ("fetch the software Vulkan driver (lavapipe): `make setup` does it in a simreel checkout; after a pip "
                f"install run `{fetch}` from simreel's source (Debian/Ubuntu)")
    if not has_nvidia_gpu():
        return f"{lavapipe}; or use a machine with a GPU"
    return ("make this machine's NVIDIA Vulkan driver usable (SAPIEN finds no Vulkan device on the GPU: install the "
            "Vulkan loader, libvulkan1, and in a container grant the graphics driver capability, e.g. "
            f"NVIDIA_DRIVER_CAPABILITIES=all); or render on the CPU: {lavapipe}, then set VK_ICD_FILENAMES to its "
            "lvp_icd.json (simreel does not choose lavapipe itself where an NVIDIA GPU is present)")


def _build_error(env_id: str, exc: Exception, *, backend: str, cfg: EnvConfig) -> Exception:
    message = " ".join(str(exc).split())  # one line
    if message == "failed to find a rendering device" or "ErrorIncompatibleDriver" in message:
        return RenderUnavailableError(
            f"{env_id}: render_backend={backend!r} but there is no render device. To render, "
            f"{no_render_device_fix()}; or pass render_backend='auto' (or 'none' with obs_mode='state')."
        )
    if message == 'failed to find device "cuda"':
        if cfg.num_envs > 1 and cfg.sim_backend in ("auto", "gpu", "cuda", "physx_cuda"):
            return EnvBuildError(
                f"{env_id}: num_envs={cfg.num_envs} needs the GPU sim (PhysX CUDA) and this machine has no CUDA "
                "device; use num_envs=1 (CPU sim), or gymnasium's AsyncVectorEnv for several CPU envs"
            )
        return EnvBuildError(f"{env_id}: a CUDA device was asked for and this machine has none ({message})")
    elsewhere = _failed_outside_maniskill(env_id, exc, message)
    if elsewhere is not None:
        return elsewhere
    if isinstance(exc, AttributeError) and "render_shapes" in message:
        return RenderUnavailableError(
            f"{env_id} reads render shapes while building its scene, which needs a render device ({message}). "
            f"To build it, {no_render_device_fix()}."
        )
    return EnvBuildError(f"{env_id}: could not build the env: {type(exc).__name__}: {message}")


def _failed_outside_maniskill(env_id: str, exc: Exception, message: str) -> Exception | None:
    """The error for a build that failed on a control mode the robot lacks (ManiSkill's check, where `check_modes`
    could not tell), in SAPIEN fetching its PhysX GPU library, or in the user's task code (its scene building or
    first reset: `task_code_error`); None otherwise."""
    mode = control_mode_error(env_id, message) if isinstance(exc, AssertionError) else None
    if mode is not None:
        return mode
    missing = _missing_physx_gpu_library(exc)
    if missing is not None:
        return EnvBuildError(f"{env_id}: {missing} ({type(exc).__name__}: {message})")
    return task_code_error(exc)


def _missing_physx_gpu_library(exc: Exception) -> str | None:
    """What to do when `exc` came out of SAPIEN's `sapien.physx.enable_gpu` and its PhysX GPU library is not on disk;
    None otherwise. SAPIEN 3.0.3 downloads that library from GitHub into ``~/.sapien/physx/<PhysX version>/`` the
    first time a process uses the GPU sim, so on a machine that cannot reach GitHub every GPU env fails to build, with
    a network error that does not say what is missing."""
    if not any(frame.name == "enable_gpu" for frame in traceback.extract_tb(exc.__traceback__)):
        return None
    import platform

    import sapien

    folder = Path.home() / ".sapien" / "physx" / sapien.physx.version()
    if (folder / "libPhysXGpu_64.so").is_file():
        return None
    arch = "linux-aarch64-so" if platform.machine() in ("aarch64", "arm64") else "linux-so"
    url = f"https://github.com/sapien-sim/physx-precompiled/releases/download/{sapien.physx.version()}/{arch}.zip"
    return (f"the GPU sim needs SAPIEN's PhysX GPU library, which is not in {folder} and could not be fetched: SAPIEN "
            f"downloads it from GitHub at first use. On a machine that reaches GitHub, download {url} and unzip it into "
            f"{folder} on this one (the file is libPhysXGpu_64.so), then run again")


def env_versions() -> dict[str, str | None]:
    """Versions of simreel, mani_skill, sapien, torch, numpy, gymnasium and Python (None: not installed).

    Read from package metadata, so nothing heavy is imported.
    """
    import platform
    from importlib import metadata

    versions: dict[str, str | None] = {}
    for key, distribution in _VERSIONED_DISTRIBUTIONS.items():
        try:
            versions[key] = metadata.version(distribution)
        except metadata.PackageNotFoundError:
            versions[key] = None
    if versions["simreel"] is None:
        from simreel import __version__

        versions["simreel"] = __version__
    versions["python"] = platform.python_version()
    return versions
