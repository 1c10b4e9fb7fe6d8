"""Why a replay diverged, where the evidence is easy to misread: a value only the task computes off at one step of a
ManiSkill file (no second instance to ask), a task whose reward changed, one corrupted state row, a hidden counter
whose one-step errors stay inside step mode's tolerance, an action altered long before the error left its
tolerance, a file without states, and step mode's own one-step errors. Real envs, real files."""

from __future__ import annotations

import h5py
import pytest
from support.maniskill_files import copy_recording, edit_sidecar, record_maniskill

from simreel.formats import open_reader, open_writer
from simreel.replay import verify_recording

NO_SECOND = "was not checked: no second instance"


@pytest.fixture(scope="module")
def pick_file(tmp_path_factory):
    """A ManiSkill RecordEpisode file of PickCube-v1 with env states: one episode of 8 steps."""
    return record_maniskill(tmp_path_factory.mktemp("pick"), "PickCube-v1", episodes=1, steps=8)


def _copy(src, dst, edit):
    """A simreel copy of episode 0 of `src`, `edit(episode)` applied."""
    with open_reader(src) as r, open_writer(dst, r.meta) as w:
        episode = r.read_episode(0)
        edit(episode)
        w.write_episode(episode)
    return dst


def _maniskill_copy(src, to, dataset, edit):
    """A copy in folder `to` of a ManiSkill file (and its sidecar) with `edit(array)` applied to traj_0/`dataset`."""
    to.mkdir()
    dst = copy_recording(src.parent, src.stem, to)
    with h5py.File(dst, "r+") as f:
        values = f[f"traj_0/{dataset}"][()]
        edit(values)
        f[f"traj_0/{dataset}"][...] = values
    return dst


def test_one_reward_off_in_a_maniskill_file_is_input_inconsistent_and_says_no_second_instance_ran(pick_file, tmp_path):
    """Only the recorded reward of step 4 is off, the steps around it reproduce. A ManiSkill file gives no second
    instance, so nothing shows state the dict lacks: the recording is named, with the check that could not run."""
    path = _maniskill_copy(pick_file, tmp_path / "rew", "rewards", lambda r: r.__setitem__(4, r[4] + 0.1))
    ep = verify_recording(path).episodes[0]
    cause = ep.explanation.cause
    assert (ep.first_divergence.step, ep.first_divergence.key) == (4, "rewards")
    assert (cause.kind, cause.step, cause.key) == ("input_inconsistent", 4, "rewards")
    assert "the recorded rewards at step 4 is not what the task computes there" in cause.summary
    assert any(line.startswith(f"whether step 4 depends on what the env held before the restore {NO_SECOND}")
               for line in cause.evidence)
    assert not any("simreel audit" in line for line in cause.evidence)


def test_every_reward_off_without_a_second_instance_is_undetermined_naming_both_possibilities(pick_file, tmp_path):
    """The sidecar names another reward mode: every step's reward is off, every state reproduced. Without a second
    instance that is a changed task as much as state the dict lacks: undetermined, naming both."""
    path = copy_recording(pick_file.parent, pick_file.stem, tmp_path)
    edit_sidecar(path, lambda doc: doc["env_info"]["env_kwargs"].__setitem__("reward_mode", "sparse"))
    cause = verify_recording(path).episodes[0].explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("undetermined", 0, "rewards")
    assert ("what the task computes is off at every step checked (0, 1, 2) while the state is reproduced: its code or "
            "build (a reward, evaluate(), the reward mode) differs from the recording's, or it depends on state its "
            "dict lacks; no second instance could tell which") in cause.summary
    assert any(NO_SECOND in line for line in cause.evidence)


def test_a_changed_reward_function_is_task_differs_not_missing_state(record, monkeypatch):
    """Every step's reward is off the same way and an instance that held another episode computes the same: the
    task's code changed, no missing state (and no `simreel audit` to send the user to)."""
    from simreel.tasks.lift_cube import LiftCubeEnv

    path = record("SimreelLiftCube-v1", 1, 20)
    original = LiftCubeEnv.compute_dense_reward
    monkeypatch.setattr(LiftCubeEnv, "compute_dense_reward", lambda self, **kw: original(self, **kw) * 1.5)
    ep = verify_recording(path).episodes[0]
    cause = ep.explanation.cause
    assert (cause.kind, cause.step, cause.key) == ("task_differs", 0, "rewards")
    assert cause.summary.startswith("task differs: from the same state the task computes something else than was "
                                    "recorded (rewards), at every step checked and alike in an instance that held "
                                    "another episode")
    assert not any("simreel audit" in line for line in cause.evidence)


def test_a_hidden_counter_under_step_tolerance_is_state_not_captured_relative_to_the_divergence(record, monkeypatch):
    """A per-instance counter in the reward: one step from a restored state stays inside step mode's reward tolerance
    (1e-2), but two instances differ by as much as the replay's own divergence: not a reproduction."""
    from simreel.tasks.lift_cube import LiftCubeEnv

    path = record("SimreelLiftCube-v1", 1, 20)
    original = LiftCubeEnv.compute_dense_reward

    def counted(self, **kwargs):
        self._reward_calls = getattr(self, "_reward_calls", 0) + 1
        return original(self, **kwargs) + 1e-4 * self._reward_calls

    monkeypatch.setattr(LiftCubeEnv, "compute_dense_reward", counted)
    ep = verify_recording(path).episodes[0]
    d, cause = ep.first_divergence, ep.explanation.cause
    assert d.key == "rewards" and d.error < 1e-2
    assert (cause.kind, cause.step, cause.key) == ("state_not_captured", d.step, "rewards")
    assert any("differs: rewards off by" in line and "× the replay's divergence" in line for line in cause.evidence)


def test_an_action_altered_before_the_steps_checked_is_found_at_the_onset(record, tmp_path):
    """With --atol 1 the replay leaves its tolerance at step 8, three steps after the altered action 5 (the onset):
    the one-step check looks there too, not only at the steps around 8."""
    path = _copy(record("SimreelLiftCube-v1", 1, 20), tmp_path / "act5.h5",
                 lambda e: e.actions.__setitem__((5, 0), e.actions[5, 0] + 0.1))
    ep = verify_recording(path, atol=1.0).episodes[0]
    cause = ep.explanation.cause
    assert ep.first_divergence.step == 8 and ep.explanation.onset.step == 5
    assert (cause.kind, cause.step) == ("input_inconsistent", 5)
    assert cause.summary.endswith("the recorded action 5 does not produce the recorded step 5 even from the exactly "
                                  "restored state, while the steps around it do")
    assert cause.evidence[-1].startswith("the state began to differ there (the first state difference: at step 5")


def _corrupt_row_7(episode):
    episode.env_states["actors/cube"][7, 0] += 0.01


def test_one_corrupted_state_row_is_named(record, tmp_path):
    """The cube's x in state row 7 moved by 1 cm: steps 6 and 7 are off from their restored states, 4, 5 and 8
    reproduce, and the replay itself (which never restored row 7) gives the recorded row 8."""
    path = _copy(record("SimreelLiftCube-v1", 1, 20), tmp_path / "st7.h5", _corrupt_row_7)
    ep = verify_recording(path).episodes[0]
    cause = ep.explanation.cause
    assert (ep.first_divergence.step, ep.first_divergence.key) == (6, "env_states/actors/cube[p]")
    assert (cause.kind, cause.step) == ("input_inconsistent", 6)
    assert cause.summary.endswith("the recorded state after step 6 (state row 7) is not what action 6 gives from the "
                                  "exactly restored state 6, and the step from it does not give the recorded state 8, "
                                  "while the steps around them reproduce the recording: that state row is off")
    assert cause.evidence[2].startswith("steps 4, 5, 8 reproduce the recording")
    assert cause.evidence[3].startswith("the replay, which stepped on from its own state 7 rather than the recorded "
                                        "one, gives the recorded state 8")


def test_step_mode_explains_with_its_own_one_step_errors_and_never_amplification(record, tmp_path):
    """In --mode step the verdict's comparison is the one-step errors: the explanation quotes its numbers. A step
    from a restored state cannot amplify an earlier difference, even where a tight tolerance makes noise diverge."""
    path = _copy(record("SimreelLiftCube-v1", 1, 20), tmp_path / "st7.h5", _corrupt_row_7)
    ep = verify_recording(path, mode="step").episodes[0]
    d, cause = ep.first_divergence, ep.explanation.cause
    assert (d.step, cause.kind, cause.step) == (6, "input_inconsistent", 6)
    assert "(state row 7)" in cause.summary and cause.summary.endswith("(or actions 6 and 7 both are)")
    assert cause.evidence[0].startswith(f"step 6 from the exactly restored state 6: {d.key} off by "
                                        f"{ep.explanation.growth[0].describe().split(': ')[1].split(' ')[0]} ")
    assert any(c.startswith("one-step errors (the replay's own (--mode step))") for c in ep.explanation.checked)

    tight = verify_recording(record("SimreelLiftCube-v1", 1, 20), mode="step", atol=1e-4).episodes[0]
    assert tight.verdict == "diverged" and tight.explanation.onset is None  # no difference carries across steps
    assert tight.explanation.cause.kind != "amplification"
    assert not any(line.startswith("onset:") for line in tight.explanation.lines())
    assert "each step alone reproduces" not in tight.explanation.cause.summary


def test_a_file_without_states_skips_what_needs_them_and_says_so(tmp_path):
    """ManiSkill recorded without env states, a flag flipped: no one-step check can run (no IndexError), and the
    explanation never says the state matched."""
    src = record_maniskill(tmp_path, "PickCube-v1", name="nostate", episodes=1, steps=8, record_env_state=False)
    path = _maniskill_copy(src, tmp_path / "term", "terminated", lambda t: t.__setitem__(3, ~t[3]))
    ep = verify_recording(path).episodes[0]
    cause = ep.explanation.cause
    assert (ep.first_divergence.step, cause.kind) == (3, "undetermined")
    assert "the file holds no states" in cause.summary and "Error" not in cause.summary
    assert cause.evidence == ["the file holds no states: the one-step errors, the second instance, the reset's state "
                              "and the other control modes need them and were not checked, and where a state "
                              "difference began cannot be told"]


def test_a_recorded_quaternion_that_is_no_rotation_is_named_in_every_mode(record, tmp_path):
    """A zeroed quaternion in the file diverges (no rotation is equal to anything); the explanation names that datum,
    not the seed (actions mode) nor missing state (states mode, where the restore keeps it as it was)."""
    def zero_cube_rotation(ep):
        ep.env_states["actors/cube"][4:, 3:7] = 0.0

    path = _copy(record("SimreelLiftCube-v1", 1, 10), tmp_path / "q0.h5", zero_cube_rotation)
    for mode in ("actions", "states", "step"):
        ep = verify_recording(path, mode=mode).episodes[0]
        cause = ep.explanation.cause
        assert (ep.verdict, cause.kind, cause.key) == ("diverged", "input_inconsistent", "env_states/actors/cube[q]"), \
            (mode, cause)
        assert "at state row 4 is [0, 0, 0, 0], no rotation (norm 0)" in cause.summary, (mode, cause.summary)
