"""The wrapper-stack policy: which wrappers may sit below a `RecordWrapper`. A replay steps and resets the task itself,
so a wrapper below the recorder that changes what a step or a reset does would make a recording no replay can
reproduce; `refuse_reshaping_wrappers` refuses each such wrapper in one line that says to put it above the recorder."""

from __future__ import annotations

import gymnasium as gym

from simreel.errors import UsageError

__all__ = ["refuse_reshaping_wrappers"]


_MANISKILL_STEP_CHANGERS = {
    "mani_skill.utils.wrappers.action_repeat.ActionRepeatWrapper": "steps the task several times in one step()",
    "mani_skill.utils.wrappers.cached_reset.CachedResetWrapper": "resets the task to cached states, not to the state "
                                                                 "its seed gives",
}
"""ManiSkill 3.0.1's plain `gym.Wrapper`s (matched by class name, so mani_skill is not imported here) that change what
a step or a reset does, and what they do. Its CPUGymWrapper is `_cpu_gym_change`."""

_GYMNASIUM_STEP_CHANGERS = {
    "Autoreset": "starts the next episode inside step(), where the recorder cannot see it: the recording would join "
                 "two episodes",
    "RepeatAction": "steps the task several times in one step()",
    "MaxAndSkipObservation": "steps the task several times in one step()",
    "AtariPreprocessing": "skips frames and adds no-op steps after each reset",
    "NormalizeReward": "changes the task's rewards",
}
"""gymnasium 1.x's plain `gym.Wrapper`s that change what a step or a reset does (those of other versions that lack one
are skipped), and what they do."""


def refuse_reshaping_wrappers(env: gym.Env, record_obs: bool) -> None:
    """Refuse, in one line that says to put it above the recorder, every wrapper below it that changes what a step or
    a reset does: a replay steps and resets the task itself, so it could never reproduce the recording.

    The rule: below the recorder, the task must step once per step() with the action the recorder records, reset
    only when the recorder resets and as its seed says, and hand back its own rewards and flags (and its own
    observations, when they are recorded). Refused are every gymnasium `ActionWrapper` and `RewardWrapper`, every
    `ObservationWrapper` when observations are recorded (by base class: ClipAction, ManiSkill's FrameStack, ...), and
    the plain wrappers of ManiSkill 3.0.1 and gymnasium 1.x that do the same (`_MANISKILL_STEP_CHANGERS`,
    `_GYMNASIUM_STEP_CHANGERS`, `_cpu_gym_change`, gymnasium's FrameStackObservation when observations are
    recorded). Accepted are those that leave steps and resets as the task's (TimeLimit, OrderEnforcing,
    PassiveEnvChecker, RecordEpisodeStatistics, rendering and array-conversion wrappers, ManiSkill's RecordEpisode,
    another RecordWrapper), and any other plain wrapper, a user's own among them: what it does cannot be known here.
    """
    e = env
    while isinstance(e, gym.Wrapper):
        change = _step_change(e, record_obs)
        if change is not None:
            name = type(e).__name__
            raise UsageError(f"RecordWrapper wraps {name}, which {change}; a replay could not reproduce the recording. "
                             f"Put {name} above RecordWrapper: {name}(RecordWrapper(env, ...), ...)")
        e = e.env


def _step_change(wrapper: gym.Wrapper, record_obs: bool) -> str | None:
    """What `wrapper` changes of a step or a reset that the recorder records (`refuse_reshaping_wrappers`), or None
    where it leaves them as the task's (or is not known to change them)."""
    return _base_class_change(wrapper, record_obs) or _library_wrapper_change(wrapper, record_obs)


def _base_class_change(wrapper: gym.Wrapper, record_obs: bool) -> str | None:
    """What a wrapper changes by its gymnasium base class: actions, rewards, observations (those only when recorded)."""
    if isinstance(wrapper, gym.ActionWrapper):
        return "changes the task's actions"
    if isinstance(wrapper, gym.RewardWrapper):
        return "changes the task's rewards"
    if record_obs and isinstance(wrapper, gym.ObservationWrapper):
        return "changes the task's observations"
    return None


def _library_wrapper_change(wrapper: gym.Wrapper, record_obs: bool) -> str | None:
    """What a plain wrapper of gymnasium or ManiSkill changes of a step or a reset, known by its class (or a class it
    derives from)."""
    for name, change in _GYMNASIUM_STEP_CHANGERS.items():
        if isinstance(wrapper, _gymnasium_classes([name])):
            return change
    if record_obs and isinstance(wrapper, _gymnasium_classes(["FrameStackObservation"])):
        return "changes the task's observations"
    classes = {f"{c.__module__}.{c.__qualname__}" for c in type(wrapper).__mro__}
    change = next((change for name, change in _MANISKILL_STEP_CHANGERS.items() if name in classes), None)
    if change is None and "mani_skill.utils.wrappers.gymnasium.CPUGymWrapper" in classes:
        return _cpu_gym_change(wrapper, record_obs)
    return change


def _cpu_gym_change(wrapper: gym.Wrapper, record_obs: bool) -> str | None:
    """What ManiSkill's CPUGymWrapper changes: it unbatches the observations (recorded ones keep the env axis), and
    with `ignore_terminations` it reports no step as terminated. Otherwise it only converts arrays to numpy."""
    if getattr(wrapper, "ignore_terminations", False):
        return "reports the task's terminated steps as not terminated (ignore_terminations=True)"
    if record_obs:
        return "unbatches the task's observations (record_obs=True records them with their env axis)"
    return None


def _gymnasium_classes(names: list[str]) -> tuple[type, ...]:
    """gymnasium's wrapper classes of these names that this gymnasium has."""
    found = (getattr(gym.wrappers, name, None) for name in names)
    return tuple(c for c in found if isinstance(c, type))
