"""Compare a recording's fingerprint (versions, sim backend, sim config) with the env that replays it.

Each difference is one line naming what differs, e.g. ``mani_skill: recorded 3.0.1, replaying 3.0.2``.
Differences are warnings, not errors: a replay on another version may still verify, and the verdict says.
"""

from __future__ import annotations

import platform
import sys
from collections.abc import Mapping
from typing import Any

from simreel.datasets.same_env import PHYSICS_NEUTRAL_VERSIONS
from simreel.model.meta import RecordingMeta
from simreel.sim.describe import sim_config_json

__all__ = ["fingerprint_differences", "resolved_sim_backend"]


def _flat(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = list(v) if isinstance(v, tuple) else v
    return out


def _loaded_version(key: str) -> str | None:
    """The version an already imported module reports (cheap), None if it is not imported or says nothing."""
    if key == "python":
        return platform.python_version()
    module = sys.modules.get(key)
    version = getattr(module, "__version__", None)
    return version if isinstance(version, str) else None


def fingerprint_differences(
    meta: RecordingMeta, unwrapped: Any, versions: Mapping[str, Any] | None = None
) -> list[str]:
    """Lines naming each difference between the recording and the replaying env (empty: same fingerprint).

    `versions` defaults to this process's (`simreel.sim.make.env_versions`); a loaded module's ``__version__``
    is tried first, package metadata (slower, ~35 ms) only when that differs from the recorded version.
    """
    diffs = _version_differences(meta.versions, versions)
    backend = getattr(getattr(unwrapped, "backend", None), "sim_backend", None)
    if backend is not None and meta.sim_backend and backend != resolved_sim_backend(meta.sim_backend, meta.num_envs):
        diffs.append(f"sim backend: recorded {_named(meta.sim_backend, meta.num_envs)}, replaying {backend}")
    now = sim_config_json(getattr(unwrapped, "sim_config", None))
    if "sim_config" in meta.unknown:  # the file gives only the overrides passed to gym.make: compare those
        now = {k: v for k, v in now.items() if k in meta.sim_config}
    return diffs + _sim_config_differences(meta.sim_config, now)


def resolved_sim_backend(name: str, num_envs: int) -> str:
    """The sim backend ManiSkill runs for ``sim_backend=name`` in an env of `num_envs` parallel envs: "auto" (its
    default, which RecordEpisode files record as given) is physx_cpu for one env and physx_cuda for more (ManiSkill
    3.0.1's `BaseEnv.__init__`), and its aliases ("cpu", "gpu", "cuda", a ":<device>" suffix) map as its
    `parse_sim_and_render_backend` maps them; a name it does not know is returned as it is."""
    from mani_skill.envs.utils.system.backend import sim_backend_name_mapping

    if name == "auto":
        return "physx_cuda" if num_envs > 1 else "physx_cpu"
    return sim_backend_name_mapping.get(name.split(":", 1)[0], name)


def _named(name: str, num_envs: int) -> str:
    """`name` as a difference line shows it: with what it resolves to when that is another name."""
    resolved = resolved_sim_backend(name, num_envs)
    return name if resolved == name else f"{name} ({resolved})"


def _version_differences(recorded: Mapping[str, Any], versions: Mapping[str, Any] | None) -> list[str]:
    full: Mapping[str, Any] | None = versions
    diffs = []
    for key in sorted(set(recorded) | set(versions or {})):
        if key in PHYSICS_NEUTRAL_VERSIONS:  # simreel's own version does not change the physics
            continue
        rec = recorded.get(key)
        now = _loaded_version(key) if versions is None else versions.get(key)
        if now != rec:
            if full is None:
                from simreel.sim.make import env_versions

                full = env_versions()
            now = full.get(key)
        if rec != now:
            diffs.append(f"{key}: recorded {rec}, replaying {now}")
    return diffs


def _sim_config_differences(recorded: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    rec_cfg, now_cfg = _flat(recorded), _flat(now)
    diffs = []
    for key in sorted(set(rec_cfg) | set(now_cfg)):
        if key in rec_cfg and key in now_cfg and rec_cfg[key] != now_cfg[key]:
            diffs.append(f"sim_config.{key}: recorded {rec_cfg[key]}, replaying {now_cfg[key]}")
        elif rec_cfg and key not in now_cfg:
            diffs.append(f"sim_config.{key}: recorded {rec_cfg[key]}, absent here")
        elif rec_cfg and key not in rec_cfg:
            diffs.append(f"sim_config.{key}: not recorded, replaying {now_cfg[key]}")
    return diffs
