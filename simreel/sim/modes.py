"""A task's observation and control modes, checked before its env is built: a typo (``--obs-mode stat``,
``--control-mode pd_joint_poss``) is one line with the close matches, not ManiSkill's assertion seconds later.

Observation modes are a fixed set (ManiSkill's `BaseEnv.SUPPORTED_OBS_MODES`, or any ``+``-joined textures where a
task takes ``any_textures``); control modes belong to the robot, and are read from its agent class where that needs
no built scene. Where it does, ManiSkill's own check, raised while the env is built, is told the same way
(`control_mode_error`)."""

from __future__ import annotations

import difflib
import inspect
import re
from collections.abc import Mapping, Sequence
from typing import Any

from simreel.errors import EnvBuildError

__all__ = ["check_modes", "control_mode_error"]

_NAMED_MODES = ("rgbd", "pointcloud", "sensor_data")
"""Observation modes ManiSkill names besides its tasks' `SUPPORTED_OBS_MODES` and the textures."""

_NOT_TEXTURES = ("state", "state_dict", "none", "pointcloud")
"""What a ``+``-joined observation mode may hold besides textures (`parse_obs_mode_to_struct`)."""


def check_modes(env_id: str, env_class: type, obs_mode: str | None, control_mode: str | None,
                env_kwargs: Mapping[str, Any]) -> None:
    """`EnvBuildError` for an observation or control mode the task does not have, naming close matches."""
    if obs_mode is not None:
        _check_obs_mode(env_id, env_class, obs_mode)
    if control_mode is not None:
        modes = _control_modes(env_class, env_kwargs)
        if modes is not None and control_mode not in modes:
            raise _mode_error(env_id, "control mode", control_mode, modes)


def control_mode_error(env_id: str, message: str) -> EnvBuildError | None:
    """ManiSkill's assertion for a control mode the robot lacks (``X not in supported modes: [...]``), as
    `check_modes` tells it; None for any other message."""
    found = re.fullmatch(r"(\S+) not in supported modes: \[(.*)\]", message)
    if found is None:
        return None
    modes = re.findall(r"'([^']*)'", found.group(2))
    return _mode_error(env_id, "control mode", found.group(1), modes)


def _check_obs_mode(env_id: str, env_class: type, obs_mode: str) -> None:
    from mani_skill.envs.utils.observations import ALL_VISUAL_TEXTURES

    supported = tuple(getattr(env_class, "SUPPORTED_OBS_MODES", ()))
    if obs_mode in supported:
        return
    textures = "any_textures" in supported
    if textures and (obs_mode in _NAMED_MODES or all(
            part in ALL_VISUAL_TEXTURES or part in _NOT_TEXTURES for part in obs_mode.split("+"))):
        return
    named = [m for m in supported if m != "any_textures"]
    if textures:
        named += [*_NAMED_MODES, *ALL_VISUAL_TEXTURES]
    raise _mode_error(env_id, "obs mode", obs_mode, list(dict.fromkeys(named)),
                      more=" or textures joined by + (e.g. rgb+depth)" if textures else "")


def _control_modes(env_class: type, env_kwargs: Mapping[str, Any]) -> Sequence[str] | None:
    """The control modes of the robot the env would load, where its agent class tells them without a scene;
    None where it does not (ManiSkill checks then, while building)."""
    from mani_skill.agents.registration import REGISTERED_AGENTS

    uid = env_kwargs.get("robot_uids")
    if uid is None:
        parameter = inspect.signature(env_class.__init__).parameters.get("robot_uids")
        uid = parameter.default if parameter is not None else None
    if not isinstance(uid, str) or uid not in REGISTERED_AGENTS:
        return None
    agent_class = REGISTERED_AGENTS[uid].agent_cls
    try:  # most agents build their controller configurations from class attributes alone
        return list(object.__new__(agent_class)._controller_configs)
    except Exception:  # noqa: BLE001 - one that reads its built articulation: ManiSkill checks while building
        return None


def _mode_error(env_id: str, what: str, given: str, modes: Sequence[str], more: str = "") -> EnvBuildError:
    close = difflib.get_close_matches(given, list(modes), n=3, cutoff=0.6)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    return EnvBuildError(f"{env_id}: no {what} {given!r}; {hint}the {what}s there are {', '.join(modes)}{more}")
