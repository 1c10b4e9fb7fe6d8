"""Why a replay diverged, on real recordings with a known cause: an altered action, a heavier cube, a task that keeps
state outside its state dict, and a replay from a restored state whose float noise grows through a grasp."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from support.maniskill_files import edit_sidecar, record_maniskill
from support.unseeded import record_unseeded

from simreel.formats import open_reader, open_writer
from simreel.replay import EpisodeReplayer, verify_recording
from simreel.sim.fingerprint import SceneDifference
from simreel.verdicts.divergence import CONTACT_THRESHOLD_N

ALTERED_STEP = 17


@pytest.fixture(scope="module")
def unseeded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("unseeded")
    return {env_id: record_unseeded(env_id, folder / f"{env_id}.h5")
            for env_id in ("SimreelLiftCube-v1", "SimreelLiftCubeLeaky-v1")}


def _altered(src, dst):
    """A copy of episode 0 of `src` whose action at ALTERED_STEP points the other way on every axis."""
    with open_reader(src) as r, open_writer(dst, r.meta) as w:
        episode = r.read_episode(0)
        a = episode.actions[ALTERED_STEP]
        episode.actions[ALTERED_STEP] = np.where(a > 0, -1.0, 1.0)
        w.write_episode(episode)
    return dst


def test_an_altered_action_is_an_input_inconsistent_with_the_recording(record, tmp_path):
    path = _altered(record("PickCube-v1", 1, 30), tmp_path / "altered.h5")
    report = verify_recording(path)
    ep = report.episodes[0]
    d = ep.first_divergence
    assert (ep.verdict, d.step, d.key) == ("diverged", ALTERED_STEP, "env_states/articulations/panda[qpos]")
    cause = ep.explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("input_inconsistent", ALTERED_STEP, d.key)
    assert cause.evidence[0].startswith(f"step {ALTERED_STEP} from the exactly restored state {ALTERED_STEP}: "
                                        "env_states/articulations/panda")
    assert cause.evidence[1].startswith(f"steps {ALTERED_STEP - 2}, {ALTERED_STEP - 1}, {ALTERED_STEP + 1}, "
                                        f"{ALTERED_STEP + 2} reproduce the recording")
    doc = json.loads(json.dumps(report.to_json()))["episodes"][0]["explanation"]
    assert (doc["cause"]["kind"], doc["cause"]["step"], doc["divergence"]["step"]) == ("input_inconsistent",
                                                                                        ALTERED_STEP, ALTERED_STEP)
    assert doc["growth"][0]["key"] == d.key and doc["growth"][0]["trend"] in ("constant offset", "grew", "shrank",
                                                                             "fluctuates")
    text = report.summary()
    assert f"why: input inconsistent with the recording at step {ALTERED_STEP}: the recorded action" in text
    assert f"error: {d.key}: " in text


@pytest.mark.parametrize("flag", ["terminated", "truncated"])
def test_a_flipped_flag_is_an_input_inconsistent_not_state_the_dict_lacks(record, tmp_path, flag):
    """The state is reproduced, only a flag the task computes differs, and alike from an instance that held another
    episode: the recording is off, not the task's state dict (no `simreel audit` to send the user to)."""
    with open_reader(record("PickCube-v1", 1, 30)) as r, open_writer(tmp_path / "flipped.h5", r.meta) as w:
        episode = r.read_episode(0)
        flags = getattr(episode, flag)
        flags[ALTERED_STEP] = not flags[ALTERED_STEP]
        w.write_episode(episode)
    ep = verify_recording(tmp_path / "flipped.h5").episodes[0]
    cause = ep.explanation.cause
    assert (ep.first_divergence.step, ep.first_divergence.key) == (ALTERED_STEP, flag)
    assert (cause.kind, cause.step, cause.key) == ("input_inconsistent", ALTERED_STEP, flag)
    assert cause.summary.endswith(f"the recorded {flag} at step {ALTERED_STEP} is not what the task computes there from "
                                  "the exactly restored state and action (the state after the step is reproduced), "
                                  "while the steps around it are")
    assert not any("simreel audit" in line for line in cause.evidence)


def test_a_file_naming_the_wrong_control_mode_is_explained_by_the_mode_that_reproduces_it(tmp_path):
    """ManiSkill recorded pd_joint_pos actions; the sidecar says pd_joint_delta_pos (the same action size, so nothing
    refuses it): the replay diverges at step 0 and the explanation finds the mode whose steps reproduce the file."""
    path = record_maniskill(tmp_path, "PickCube-v1", name="demos", episodes=1, steps=6)

    def relabel(doc):
        doc["env_info"]["env_kwargs"]["control_mode"] = "pd_joint_delta_pos"
        for episode in doc["episodes"]:
            episode["control_mode"] = "pd_joint_delta_pos"

    edit_sidecar(path, relabel)
    ep = verify_recording(path).episodes[0]
    assert (ep.verdict, ep.first_divergence.step) == ("diverged", 0)
    cause = ep.explanation.cause
    assert (cause.kind, cause.step) == ("control_mode_differs", 0)
    assert cause.summary == ("control mode differs: the recorded actions give the recorded states in pd_joint_pos, not "
                             "in pd_joint_delta_pos, the control mode the recording names")
    assert cause.evidence[0].startswith("steps 0, 1, 2, each from its restored state: not reproduced in "
                                        "pd_joint_delta_pos (")
    assert "reproduced in pd_joint_pos (" in cause.evidence[0]


def test_actions_no_control_mode_reproduces_are_undetermined_and_say_what_was_checked(record, tmp_path):
    """Every action altered: no step is reproduced from its restored state in the recorded mode nor in another of the
    same size, and the explanation says so instead of claiming each step alone reproduces the recording."""
    with open_reader(record("PickCube-v1", 1, 30)) as r, open_writer(tmp_path / "noise.h5", r.meta) as w:
        episode = r.read_episode(0)
        episode.actions[:] = np.where(episode.actions > 0, -1.0, 1.0)
        w.write_episode(episode)
    cause = verify_recording(tmp_path / "noise.h5").episodes[0].explanation.cause
    assert cause.kind == "undetermined"
    assert cause.summary.startswith("undetermined: the scene matches, steps 0, 1, 2 are not reproduced from their "
                                    "restored states, the difference did not start")
    assert "each step alone reproduces" not in cause.summary
    assert ("the robot's other control modes with actions of the recorded size (pd_joint_pos, "
            "pd_joint_target_delta_pos, pd_joint_vel): none reproduces steps 0, 1, 2") in cause.summary


def test_another_build_is_not_blamed_for_what_a_step_explains(record, tmp_path):
    """Version differences are named as the cause only when no step-level cause holds: here the altered action
    explains the divergence, and the other Python release is one of the things checked, not the reason."""
    from simreel.model.components import Tolerances
    from simreel.replay.explain.explain import ExplainContext, explain_divergence
    from simreel.verdicts.compare import compare_episode

    path = _altered(record("PickCube-v1", 1, 30), tmp_path / "altered.h5")
    with open_reader(path) as r:
        meta, recorded = r.meta, r.read_episode(0)
    with EpisodeReplayer(meta) as replayer:
        replayed = replayer.replay(recorded)
        cmp = compare_episode(recorded, replayed.episode, Tolerances.for_mode("actions"), channels=meta.contact_channels)
        ctx = ExplainContext(mode="actions", resync=None, channels=list(meta.contact_channels), env_id=meta.env_id,
                             build_differences=["python: recorded 3.11.6, replaying 3.11.7"])
        cause = explain_divergence(replayer, recorded, replayed, cmp, ctx).cause
    assert (cause.kind, cause.step) == ("input_inconsistent", ALTERED_STEP)


def test_a_heavier_cube_is_named_before_any_step_is_compared(record, monkeypatch):
    path = record("SimreelLiftCube-v1", 1, 20)
    from simreel.tasks.lift_cube import LiftCubeEnv

    monkeypatch.setattr(LiftCubeEnv, "cube_mass", 0.08)  # the task's builder changed since the recording
    with open_reader(path) as r:
        meta, episode = r.meta, r.read_episode(0)
    assert meta.scene_fingerprint["bodies"]["cube"]["mass"] == 0.064
    with EpisodeReplayer(meta) as replayer:
        replayer.reset_for(episode.meta)
        found = replayer.scene_check(episode.meta)  # right after the reset: no step taken
    assert found[0] == SceneDifference("cube", "mass", 0.064, 0.08)

    report = verify_recording(path)
    ep = report.episodes[0]
    assert ep.verdict == "diverged" and ep.scene_differences == found
    cause = ep.explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("scene_differs", None, None)
    assert "(cube: mass 0.064 → 0.08), found at the reset before any step was compared" in cause.summary
    assert cause.evidence[0] == "cube: mass 0.064 → 0.08"
    text = report.summary()
    assert "why: the replaying scene differs from the recorded one (cube: mass 0.064 → 0.08)" in text
    # a scene difference that did not make the replay diverge is still shown
    within = dataclasses.replace(ep, verdict="within_tolerance", explanation=None)
    lines = dataclasses.replace(report, episodes=[within]).summary().splitlines()
    assert lines[3].strip().startswith("scene differs from the recording (found at the reset): cube: mass 0.064 → 0.08;")
    assert report.to_json()["episodes"][0]["scene_differences"][0] == {
        "subject": "cube", "property": "mass", "recorded": 0.064, "replaying": 0.08, "text": "cube: mass 0.064 → 0.08"}


def test_the_leaky_task_is_explained_as_state_not_captured(unseeded):
    report = verify_recording(unseeded["SimreelLiftCubeLeaky-v1"])
    ep = report.episodes[0]
    d = ep.first_divergence
    assert (d.step, d.key) == (0, "info/height_error")  # the goal height is the replaying env's own
    cause = ep.explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("state_not_captured", 0, "info/height_error")
    assert any(line.startswith("the state after step 0 is reproduced") and "info/height_error" in line
               for line in cause.evidence)
    assert "simreel audit SimreelLiftCubeLeaky-v1" in cause.evidence[-1]


def test_a_restore_then_replay_is_amplification_through_a_contact(unseeded):
    path = unseeded["SimreelLiftCube-v1"]
    with open_reader(path) as r:
        meta, episode = r.meta, r.read_episode(0)
    fingers = [c for c, ch in enumerate(meta.contact_channels) if ch.kind == "pair" and "finger" in ch.bodies[0]]
    touching = np.linalg.norm(episode.contact_forces[:, fingers], axis=-1).max(axis=1) > CONTACT_THRESHOLD_N
    touch = int(np.argmax(touching))  # the step the fingers first touch the cube

    report = verify_recording(path)
    ep = report.episodes[0]
    assert "actions replayed from the recorded initial state" in ep.limits  # the replay restored that state
    d = ep.first_divergence
    assert d.key.startswith("env_states/actors/cube[") and touch <= d.step <= touch + 1
    explanation = ep.explanation
    cause = explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("amplification", d.step, d.key)
    onset = explanation.onset
    assert onset.float_noise and onset.step < touch and onset.growth > 100
    assert f"step {touch}: contact panda/panda_" in cause.summary and "cube begins" in cause.summary
    assert any(e.kind == "contact_begins" and e.step == touch for e in explanation.events)
    # one step from the restored state at the touch already puts the cube most of the way off: said, not hidden
    assert cause.evidence[1].startswith(f"step {d.step} alone is within step mode's tolerances (")
    assert f"one step alone puts {d.key} off by " in cause.evidence[1] and "of the replay's own divergence" in \
        cause.evidence[1]


def test_a_changed_seed_is_an_input_inconsistent_with_the_recording_at_the_reset(record, tmp_path):
    """The recorded seed no longer gives the recorded initial state (here: it was changed after recording): two
    resets with it agree with each other, not with the recording, so the input is named, not the task's reset."""
    src = record("PickCube-v1", 1, 30)
    path = tmp_path / "reseeded.h5"
    with open_reader(src) as r, open_writer(path, r.meta) as w:
        episode = r.read_episode(0)
        w.write_episode(dataclasses.replace(episode, meta=dataclasses.replace(episode.meta, seed=episode.meta.seed + 1)))
    ep = verify_recording(path).episodes[0]
    d = ep.first_divergence
    assert (ep.verdict, d.at) == ("diverged", "reset")
    cause = ep.explanation.cause
    assert (cause.kind, cause.step) == ("input_inconsistent", -1)
    assert cause.key.startswith("env_states/actors/cube[")  # the cube is placed from the seed
    assert cause.summary.startswith("input inconsistent with the recording at the reset: seed 4 gives the same "
                                    "initial state twice, but not the recorded one (env_states/actors/cube[")
    assert cause.evidence[0] == "reset 1 vs reset 2: identical"
