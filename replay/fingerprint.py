"""Compare a recording's fingerprint (versions, sim backend, sim config) with the env that replays it.

Each difference is one line naming what differs, e.g. ``mani_skill: recorded 3.0.1, replaying 3.0.2``.
Differences are warnings, not errors: a replay on another version may still verify, and the verdict says.
"""

from __future__ import annotations

import platform
import sys
from collections.abc import Mapping
from typing import Any

from simreel.env_meta import sim_config_json
from simreel.episode import RecordingMeta

__all__ = ["fingerprint_differences"]

_IGNORED_VERSIONS = ("simreel",)
"""simreel's own version does not change the physics."""


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

    `versions` defaults to this process's (`simreel.envs.env_versions`); a loaded module's ``__version__``
    is tried first, package metadata (slower, ~35 ms) only when that differs from the recorded version.
    """
    diffs: list[str] = []
    full: Mapping[str, Any] | None = versions
    keys = set(meta.versions) | set(versions or {})
    for key in sorted(keys):
        if key in _IGNORED_VERSIONS:
            continue
        rec = meta.versions.get(key)
        now = _loaded_version(key) if versions is None else versions.get(key)
        if now != rec and full is None:
            from simreel.envs import env_versions

            full = env_versions()
        if now != rec and full is not None:
            now = full.get(key)
        if rec != now:
            diffs.append(f"{key}: recorded {rec}, replaying {now}")
    backend = getattr(getattr(unwrapped, "backend", None), "sim_backend", None)
    if backend is not None and meta.sim_backend and backend != meta.sim_backend:
        diffs.append(f"sim backend: recorded {meta.sim_backend}, replaying {backend}")
    rec_cfg, now_cfg = _flat(meta.sim_config), _flat(sim_config_json(getattr(unwrapped, "sim_config", None)))
    for key in sorted(set(rec_cfg) | set(now_cfg)):
        if key in rec_cfg and key in now_cfg and rec_cfg[key] != now_cfg[key]:
            diffs.append(f"sim_config.{key}: recorded {rec_cfg[key]}, replaying {now_cfg[key]}")
        elif rec_cfg and key not in now_cfg:
            diffs.append(f"sim_config.{key}: recorded {rec_cfg[key]}, absent here")
        elif rec_cfg and key not in rec_cfg:
            diffs.append(f"sim_config.{key}: not recorded, replaying {now_cfg[key]}")
    return diffs
