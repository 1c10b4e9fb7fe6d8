"""How an `simreel.replay.run.engine.EpisodeReplayer` builds and drives its env (`ReplayerOptions`), each option
checked as it is given."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from simreel.options.checks import check_flag, check_mapping, check_text, text_tuple

__all__ = ["ReplayerOptions"]


@dataclass(frozen=True)
class ReplayerOptions:
    """How an `EpisodeReplayer` builds and drives its env.

    Attributes:
        obs_mode: observation mode of the replay (None: the recorded one when observations are needed, else
            ``"none"``, which skips computing observations; the physics is the same).
        need_obs: compute and return observations (for comparing recorded ones or writing ``-o``).
        need_rewards: compute rewards. False (the recording holds none and nothing writes the replay) builds the
            env with ``reward_mode="none"`` where the task allows it: rewards are read-only functions of the
            state, so the physics is the same and no reward is computed that nothing could check.
        pose_bodies: also sample the world pose of these bodies after reset and every step (for ``-o``).
        render_backend: None: ``"none"`` unless the observation mode needs cameras, then ``"auto"``.
        sim_backend: None: the recorded one.
        control_mode: None: the recorded one (another one to replay converted actions: `simreel.replay.convert.replayer`).
        env_kwargs: ``gym.make`` arguments added to the recorded ones (camera size, shader).
    """

    obs_mode: str | None = None
    need_obs: bool = False
    need_rewards: bool = True
    pose_bodies: tuple[str, ...] = ()
    render_backend: str | None = None
    sim_backend: str | None = None
    control_mode: str | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Check every option's type, so that a wrong one is a `UsageError` here, naming it and what to give, before
        the env is built: not a raw error inside ManiSkill, nor a value taken for another (``need_obs="no"`` as yes,
        ``pose_bodies="cube"`` as four bodies of one letter each). Put them in one form: the bodies as a tuple,
        the env's arguments as a dict."""
        for name in ("need_obs", "need_rewards"):
            check_flag(name, getattr(self, name))
        for name, what in _TEXT_OPTIONS.items():
            check_text(name, getattr(self, name), what, optional=True)
        object.__setattr__(self, "pose_bodies", text_tuple("pose_bodies", self.pose_bodies, "the names of the bodies "
                                                           'whose poses to sample, as a tuple of strings, e.g. ("cube", '
                                                           '"panda/panda_hand")'))
        check_mapping("env_kwargs", self.env_kwargs, 'the gym.make arguments to add as a dict, e.g. '
                      '{"shader_dir": "rt"}')
        object.__setattr__(self, "env_kwargs", dict(self.env_kwargs))


_TEXT_OPTIONS = {
    "obs_mode": 'an observation mode as a string, e.g. "rgb", or None (the recorded one when needed)',
    "render_backend": 'a render backend as a string, e.g. "cpu", or None (the one the observation mode needs)',
    "sim_backend": 'a sim backend as a string, e.g. "physx_cpu", or None (the recorded one)',
    "control_mode": 'a control mode as a string, e.g. "pd_ee_delta_pose", or None (the recorded one)',
}
"""`ReplayerOptions`' options that are strings or None, and what each means."""
