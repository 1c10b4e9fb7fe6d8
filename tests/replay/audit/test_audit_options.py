"""`AuditOptions` and `audit_task` from Python: a value of the wrong type or range, an option that would be ignored,
an unknown keyword, is one `UsageError` naming it and what to give, raised when the options are built, before any env
is built; `simreel audit` says the same in one line (exit 2). The forms the CLI and Python use stay valid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import simreel.replay.audit.audit as audit
from simreel.cli.main import main
from simreel.errors import UsageError
from simreel.model.selection import EpisodeSelection
from simreel.replay import AuditOptions, audit_task

STEPS = "give the number of random steps before the restore, an int >= 1"
SEED = "give the seed of the first instance, an int >= 0"
SEED_RANGE = ("but ManiSkill takes seeds from 0 to 4294967295; choose a seed, or fewer episodes (--episodes), that "
              "keeps them in that range")
SELECTION = 'give episode indices, ints >= 0 (e.g. [0, 3]), their text as --episodes takes it ("0,3-7"), or None (all)'


def _policy(env, obs):
    return env.action_space.sample()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"steps": "3"}, f"steps='3': {STEPS}"),  # was: TypeError '<' not supported between 'str' and 'int'
        ({"steps": True}, f"steps=True: {STEPS}"),  # was: an audit of 1 step
        ({"steps": 2.5}, f"steps=2.5: {STEPS}"),  # was: TypeError, once the env was built
        ({"steps": float("nan")}, f"steps=nan: {STEPS}"),  # was: the same
        ({"steps": 0}, "--steps must be >= 1, got 0"),
        ({"seed": -1}, f"--seed -1: this audit would use seeds -1 to 1, {SEED_RANGE}"),  # was: gymnasium's Error
        # once the env was built
        ({"seed": 2**32 - 2}, f"--seed 4294967294: this audit would use seeds 4294967294 to 4294967296, {SEED_RANGE}"),
        # was: numpy's ValueError inside the third reset, once the env was built
        ({"seed": 2**32 - 10, "policy": _policy, "episodes": 12},
         f"--seed 4294967286: this audit would use seeds 4294967286 to 4294967297, {SEED_RANGE}"),
        ({"seed": 1.5}, f"seed=1.5: {SEED}"),  # was: gymnasium's Error once the env was built
        ({"seed": None}, f"seed=None: {SEED}"),  # was: TypeError NoneType + int, once the env was built
        ({"imports": 5}, 'imports=5: give the .py files or modules that register the task, as a tuple of strings, '
                         'e.g. ("my_tasks.py",)'),  # was: EnvBuildError --import 5: AttributeError
        ({"control_mode": 5}, 'control_mode=5: give a control mode as a string, e.g. "pd_ee_delta_pos", or None (the '
                              "task's)"),  # was: ManiSkill's AssertionError from gym.make
        ({"obs_mode": 5}, 'obs_mode=5: give an observation mode as a string, e.g. "state", or None (the task\'s)'),
        # was: AttributeError 'int' object has no attribute 'split'
        ({"reward_mode": 5}, 'reward_mode=5: give a reward mode as a string, e.g. "dense", or None (the task\'s)'),
        ({"env_kwargs": [1]}, 'env_kwargs=[1]: give the gym.make arguments as a dict, e.g. {"robot_uids": "panda"}'),
        # was: TypeError cannot convert dictionary update sequence element
        ({"trajectory": 5}, "trajectory=5: give the recording to audit along, a str or pathlib.Path, or None"),
        ({"trajectory": "a.h5", "trajectory_episodes": 5},
         f"trajectory_episodes=5: not a list of indices; {SELECTION}"),
        ({"trajectory_episodes": [0]}, "trajectory_episodes picks episodes of the trajectory: give the recording "
                                       "(--trajectory)"),  # was: ignored
        ({"policy": 5}, "policy=5: give a callable policy(env, obs) -> action, or None"),  # was: TypeError 'int'
        # object is not callable, after the random-action audit
        ({"policy": _policy, "policy_name": 5}, 'policy_name=5: give what the policy is called in findings, a string, '
                                                'e.g. "--policy scripted"'),
        ({"policy": _policy, "episodes": "2"}, "episodes='2': give the number of the policy's episodes, an int >= 1"),
        ({"episodes": 3}, "--episodes 3 is the number of episodes of a policy: give the policy (--policy)"),  # was:
        # ignored
        ({"every": True, "policy": _policy}, "every=True: give the number of steps between two restores along a "
                                             "trajectory, an int >= 1"),  # was: taken as 1
        ({"every": 3}, "--every 3 restores along a trajectory: give one (--trajectory or --policy)"),  # was: ignored
        ({"bogus": 1}, "bogus=1: give only the options AuditOptions has: imports, trust_recorded_imports, steps, seed, control_mode, obs_mode, "
                       "reward_mode, env_kwargs, trajectory, trajectory_episodes, policy, policy_name, episodes, "
                       "every"),  # was: TypeError AuditOptions.__init__() got an unexpected keyword argument
    ],
    ids=["steps-str", "steps-bool", "steps-float", "steps-nan", "steps-0", "seed-negative", "seed-past-range",
         "seed-policy-past-range", "seed-float", "seed-none",
         "imports-int", "control_mode-int", "obs_mode-int", "reward_mode-int", "env_kwargs-list", "trajectory-int",
         "trajectory_episodes-int", "trajectory_episodes-alone", "policy-int", "policy_name-int", "episodes-str",
         "episodes-alone", "every-bool", "every-alone", "unknown"],
)
def test_a_bad_option_is_one_usage_error_before_any_env_is_built(monkeypatch, options, message):
    built = []
    monkeypatch.setattr(audit, "build_with_render_fallback", lambda *a, **k: built.append(a))  # every env's build
    if "bogus" not in options:
        with pytest.raises(UsageError) as refused:
            AuditOptions(**options)
        assert str(refused.value) == message
    with pytest.raises(UsageError) as refused:  # the same through audit_task's keywords
        audit_task("PickCube-v1", **options)
    assert str(refused.value) == message
    assert built == []


@pytest.mark.parametrize(
    ("env_id", "options", "message"),
    [
        (5, None, 'env_id=5: give the task\'s env id as a string, e.g. "PickCube-v1", or None (with trajectory: the '
                  "recording's)"),  # was: AttributeError 'int' object has no attribute 'startswith'
        ("PickCube-v1", {"steps": 2}, "options={'steps': 2}: give an AuditOptions, or its fields as keywords, e.g. "
                                      "audit_task(env_id, steps=10)"),  # was: TypeError from dataclasses.replace
    ],
    ids=["env_id-int", "options-dict"],
)
def test_an_env_id_or_options_of_the_wrong_type_is_one_usage_error(env_id, options, message):
    with pytest.raises(UsageError) as refused:
        audit_task(env_id, options)
    assert str(refused.value) == message


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seed", "-1"], f"--seed -1: this audit would use seeds -1 to 1, {SEED_RANGE}"),  # was: "internal error: Error: Seed must be greater or
        # equal to zero", exit 3, once the env was built
        (["--every", "3"], "--every 3 restores along a trajectory: give one (--trajectory or --policy)"),  # was:
        # ignored, exit 0
    ],
    ids=["seed-negative", "every-alone"],
)
def test_the_cli_says_it_in_one_line(args, message, capsys):
    assert main(["audit", "PickCube-v1", "--steps", "2", *args]) == 2
    assert capsys.readouterr().err.splitlines() == [f"simreel audit: error: {message}"]


def test_the_forms_the_cli_and_python_use_stay_valid_and_one_string_is_one_name(record):
    """Regression: `imports="tasks.py"` was one spec per character ("no module named 't'")."""
    opts = AuditOptions(imports="simreel.tasks", steps=np.int64(2), seed=np.int32(1), env_kwargs={},
                        trajectory=Path("a.h5"), trajectory_episodes="0,2-3", every=np.int64(2))
    assert (opts.imports, opts.steps, opts.seed, opts.trajectory, opts.every) == (("simreel.tasks",), 2, 1, "a.h5", 2)
    assert (type(opts.steps), type(opts.seed)) == (int, int)
    assert opts.trajectory_episodes == EpisodeSelection(((0, 0), (2, 3)))
    assert AuditOptions(imports=["a.py", "b"], policy=_policy, episodes=2).imports == ("a.py", "b")
    report = audit_task(None, AuditOptions(steps=2), trajectory=Path(record("PickCube-v1", 2, 20)),
                        trajectory_episodes=[1], every=10)
    assert report.env_id == "PickCube-v1" and report.steps == 2
    assert any("episode 1 of" in check for check in report.checks), report.checks
