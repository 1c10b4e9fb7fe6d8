"""simreel.verdicts.compare (and simreel.model.components): per-leaf errors, quaternion-aware comparison, tolerances and the first divergence (pure numpy)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from simreel.model.components import DEFAULT_TOLERANCES, GROUPS, Tolerances, component_error, components_of
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel, EpisodeMeta
from simreel.verdicts.compare import CompareScope, compare_episode


def _episode(T: int = 4, seed: int = 0) -> Episode:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(T + 1, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    cube = np.concatenate([rng.normal(size=(T + 1, 3)), q, rng.normal(size=(T + 1, 6))], axis=1).astype(np.float32)
    panda = rng.normal(size=(T + 1, 13 + 2 * 2)).astype(np.float32)
    panda[:, 3:7] = q
    return Episode(
        meta=EpisodeMeta(index=0, seed=seed, length=T),
        actions=np.zeros((T, 2), np.float32),
        rewards=rng.normal(size=T).astype(np.float32),
        terminated=np.zeros(T, bool),
        truncated=np.zeros(T, bool),
        success=np.zeros(T, bool),
        fail=np.zeros(T, bool),
        env_states={"actors/cube": cube, "articulations/panda": panda, "goal_height": rng.normal(size=(T + 1,)).astype(np.float32)},
        info={"is_grasped": np.zeros(T, bool), "height_error": rng.normal(size=T).astype(np.float32)},
        contact_forces=rng.normal(size=(T, 2, 3)).astype(np.float32),
    )


def _copy(ep: Episode) -> Episode:
    return dataclasses.replace(
        ep,
        rewards=ep.rewards.copy(),
        success=ep.success.copy(),
        env_states={k: v.copy() for k, v in ep.env_states.items()},
        info={k: v.copy() for k, v in ep.info.items()},
        contact_forces=ep.contact_forces.copy(),
    )


CHANNELS = [ContactChannel("net", ("cube",)), ContactChannel("pair", ("panda/finger", "cube"))]
TOL = Tolerances.for_mode("actions")


def test_components_name_every_part_of_a_leaf():
    keys = [(c.key, c.group, c.quat) for c in components_of("actors/cube", (13,))]
    assert keys == [
        ("env_states/actors/cube[p]", "pos", False),
        ("env_states/actors/cube[q]", "quat", True),
        ("env_states/actors/cube[v]", "vel", False),
        ("env_states/actors/cube[w]", "vel", False),
    ]
    art = [(c.key, c.start, c.stop) for c in components_of("articulations/panda", (31,))]
    assert art[-2:] == [("env_states/articulations/panda[qpos]", 13, 22), ("env_states/articulations/panda[qvel]", 22, 31)]
    assert [c.key for c in components_of("controller/arm/target_pose", (7,))] == [
        "env_states/controller/arm/target_pose[p]", "env_states/controller/arm/target_pose[q]"]
    assert [c.group for c in components_of("controller/arm/target_qpos", (7,))] == ["controller"]
    assert [(c.key, c.group) for c in components_of("goal_height", ())] == [("env_states/goal_height", "custom")]


def test_quaternions_compare_as_rotations():
    q = np.array([[0.5, 0.5, -0.5, 0.5]])
    comp = components_of("actors/x", (13,))[1]
    a = np.zeros((1, 13))
    a[:, 3:7] = q
    b = a.copy()
    b[:, 3:7] = -q
    assert component_error(a, b, comp)[0] == 0.0  # q and -q: the same rotation
    angle = 0.01
    r = np.array([math.cos(angle / 2), math.sin(angle / 2), 0, 0])  # rotation by 0.01 rad about x
    w1, x1, y1, z1 = r
    w2, x2, y2, z2 = q[0]
    b[:, 3:7] = [[w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                  w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2]]
    assert component_error(a, b, comp)[0] == pytest.approx(angle, rel=1e-6)


def test_a_quaternion_that_is_no_rotation_is_never_equal_even_to_itself():
    """Normalised, [0, 0, 0, 0] was 0 rad from anything and 2q 0 rad from q: such rows are inf; a norm off 1 by float
    noise is still a rotation, and q, -q still the same one."""
    comp = components_of("actors/x", (13,))[1]
    q = np.array([0.5, 0.5, -0.5, 0.5])

    def rows(*quats: np.ndarray) -> np.ndarray:
        out = np.zeros((len(quats), 13))
        out[:, 3:7] = quats
        return out

    zero, doubled, noisy = np.zeros(4), 2 * q, q * (1 + 3e-7)
    err = component_error(rows(zero, doubled, zero, doubled, q), rows(q, q, zero, doubled, doubled), comp)
    assert np.isinf(err).all()
    assert component_error(rows(noisy, q, noisy), rows(noisy, -q, -noisy), comp).tolist() == [0.0, 0.0, 0.0]
    assert component_error(rows(noisy), rows(q), comp)[0] < 1e-6
    ep = _episode()
    ep.env_states["actors/cube"][2, 3:7] = 0.0
    cmp = compare_episode(ep, _copy(ep), TOL)  # a restored state keeps a zeroed quaternion: both sides hold it
    assert (cmp.verdict, cmp.first_divergence.key, cmp.first_divergence.step) == ("diverged", "env_states/actors/cube[q]", 1)


def test_identical_episodes_are_exact():
    ep = _episode()
    cmp = compare_episode(ep, _copy(ep), TOL, channels=CHANNELS)
    assert cmp.verdict == "exact" and cmp.first_divergence is None and cmp.ok
    assert set(cmp.max_abs_error) >= {"env_states/actors/cube[q]", "env_states/goal_height", "rewards", "success",
                                      "info/is_grasped", "contacts/cube", "contacts/panda/finger:cube"}


def test_small_errors_are_within_tolerance():
    ep = _episode()
    rep = _copy(ep)
    rep.env_states["actors/cube"][2, 0] += 1e-7
    rep.rewards[1] += 1e-7
    cmp = compare_episode(ep, rep, TOL, channels=CHANNELS)
    assert cmp.verdict == "within_tolerance"
    assert cmp.max_abs_error["env_states/actors/cube[p]"] == pytest.approx(1e-7, rel=0.5)  # float32 rounding


def test_first_divergence_names_step_key_error_and_tolerance():
    ep = _episode()
    rep = _copy(ep)
    rep.env_states["articulations/panda"][3, 13] += 0.5  # qpos after action 2
    rep.env_states["actors/cube"][4, 0] += 0.5  # later
    rep.rewards[2] += 1.0  # same step, but state comes first
    cmp = compare_episode(ep, rep, TOL, channels=CHANNELS)
    assert cmp.verdict == "diverged"
    d = cmp.first_divergence
    assert (d.step, d.key, d.at) == (2, "env_states/articulations/panda[qpos]", "step")
    assert d.error == pytest.approx(0.5, rel=1e-5) and d.tolerance == DEFAULT_TOLERANCES["actions"]["qpos"]
    assert cmp.diverged_keys["env_states/actors/cube[p]"] == 3
    assert cmp.diverged_keys["rewards"] == 2
    assert "step 2: env_states/articulations/panda[qpos] off by 0.5" in d.describe()
    json.dumps(d.to_json())


def test_initial_state_mismatch_is_reported_at_reset():
    ep = _episode()
    rep = _copy(ep)
    rep.env_states["goal_height"][0] += 0.1
    d = compare_episode(ep, rep, TOL).first_divergence
    assert (d.at, d.step, d.key) == ("reset", 0, "env_states/goal_height")
    assert compare_episode(ep, rep, TOL, scope=CompareScope(initial=False)).verdict == "exact"


def test_flags_and_integer_info_are_exact():
    ep = _episode()
    rep = _copy(ep)
    rep.success[1] = True
    cmp = compare_episode(ep, rep, Tolerances.for_mode("step", atol=1e9))
    assert cmp.verdict == "diverged"
    assert (cmp.first_divergence.key, cmp.first_divergence.step, cmp.first_divergence.tolerance) == ("success", 1, 0.0)


def test_a_value_that_is_not_finite_fails_the_check_even_on_both_sides():
    """NaN on both sides was "exact": a NaN restored into a static body reads back as the same NaN."""
    ep = _episode()
    rep = _copy(ep)
    rep.env_states["goal_height"][2] = np.nan
    cmp = compare_episode(ep, rep, TOL)
    assert cmp.first_divergence.key == "env_states/goal_height" and math.isinf(cmp.first_divergence.error)
    assert cmp.first_divergence.to_json()["error"] == "inf"
    step = cmp.first_divergence.step
    for bad in (np.nan, np.inf):
        ep.env_states["goal_height"][2] = rep.env_states["goal_height"][2] = bad
        cmp = compare_episode(ep, rep, TOL)  # identical arrays: the cheap path checks them too
        assert (cmp.verdict, cmp.first_divergence.key, cmp.first_divergence.step) == (
            "diverged", "env_states/goal_height", step)
        rep.env_states["goal_height"][2] = 0.5  # one side only: the comparison path
        assert compare_episode(ep, rep, TOL).first_divergence.step == step


def test_contact_channels_are_named():
    ep = _episode()
    rep = _copy(ep)
    rep.contact_forces[1, 1, 2] += 5.0
    d = compare_episode(ep, rep, TOL, channels=CHANNELS).first_divergence
    assert (d.key, d.step) == ("contacts/panda/finger:cube", 1)
    assert compare_episode(ep, rep, TOL, channels=CHANNELS, scope=CompareScope(contacts=False)).verdict == "exact"


def test_tolerances_per_mode_and_overrides():
    assert set(DEFAULT_TOLERANCES) == {"actions", "states", "step", "resync"}
    for values in DEFAULT_TOLERANCES.values():
        assert set(values) == set(GROUPS) and values["flag"] == 0.0
    assert Tolerances.for_mode("step")["pos"] > Tolerances.for_mode("actions")["pos"]
    t = Tolerances.for_mode("actions", atol=0.5, groups={"contact": 7})
    assert t["pos"] == 0.5 and t["contact"] == 7 and t["flag"] == 0.0
    with pytest.raises(ValueError, match="unknown tolerance group 'nope'"):
        Tolerances.for_mode("actions", groups={"nope": 1})
    with pytest.raises(ValueError, match="unknown mode"):
        Tolerances.for_mode("sideways")


def test_length_mismatch_is_an_error():
    ep = _episode(T=4)
    with pytest.raises(ValueError, match="replay has 3 steps, recording 4"):
        compare_episode(ep, _episode(T=3), TOL)


def test_observation_keys_that_cannot_be_compared_are_named_never_skipped_silently():
    """A recorded observation the replay lacks, or holds in another shape, is not compared and says so; the
    verdict holds for the keys compared."""
    rec = _episode()
    rng = np.random.default_rng(1)
    obs = {"agent/qpos": rng.normal(size=(5, 9)), "agent/qvel": rng.normal(size=(5, 9)), "extra/tcp": np.ones((5, 7))}
    rec = dataclasses.replace(rec, obs={"agent/qpos": obs["agent/qpos"], "agent/qvel": obs["agent/qvel"][:, :8],
                                        "extra/tcp_renamed": obs["extra/tcp"]})
    rep = dataclasses.replace(_copy(rec), obs=obs)
    cmp = compare_episode(rec, rep, TOL, scope=CompareScope(contacts=False))
    assert cmp.verdict == "exact" and "obs/agent/qpos" in cmp.errors
    assert cmp.not_compared == ["obs/agent/qvel not compared: (8,) a row in the file, (9,) in the replay",
                                "obs/extra/tcp_renamed not compared: the replay's observation has no such key"]
    assert compare_episode(rep, _copy(rep), TOL).not_compared == []


def test_info_the_replay_lacks_is_named_never_compared():
    """A recorded info entry the replay lacks (its task no longer returns it) is not compared and says so, whether
    the replayed episode lacks it or a block replay says the task never returned it (its rows are only zeros)."""
    from simreel.verdicts.compare import BlockComparison

    rec = _episode()
    rep = _copy(rec)
    del rep.info["is_grasped"]
    line = "info/is_grasped not compared: the replay's info has no such key"
    cmp = compare_episode(rec, rep, TOL)
    assert cmp.verdict == "exact" and cmp.not_compared == [line] and "info/is_grasped" not in cmp.max_abs_error
    blocks = BlockComparison(TOL)
    blocks.reset(rec.reset_block(), _copy(rec).reset_block())
    blocks.steps(rec.steps_block(), _copy(rec).steps_block())
    blocks.info_not_returned(["is_grasped"])
    cmp = blocks.comparison()
    assert cmp.not_compared == [line] and "info/is_grasped" not in cmp.max_abs_error | cmp.tolerance
    assert "info/height_error" in cmp.max_abs_error


@pytest.mark.parametrize("bad", [math.nan, -1.0, math.inf, "x", True], ids=["nan", "negative", "inf", "text", "bool"])
def test_a_tolerance_that_is_not_a_finite_number_at_least_0_is_refused(bad):
    """Regression: from Python a NaN group tolerance passed every comparison (a perturbed recording replayed "within
    tolerance", all verified), and a negative one failed an exact match; only --atol/--tol on the command line were
    checked. A bool was taken for a tolerance of 1 (or 0)."""
    from simreel.errors import UsageError
    from simreel.replay import ReplayOptions

    with pytest.raises(ValueError, match="a tolerance must be a finite number >= 0|is not a number"):
        Tolerances.for_mode("actions", groups={"contact": bad})
    with pytest.raises(ValueError, match="a tolerance must be a finite number >= 0|is not a number"):
        Tolerances.for_mode("actions", atol=bad)
    with pytest.raises(UsageError, match="tolerance pos"):
        ReplayOptions(group_tolerances={"pos": bad}).tolerances()
