"""`simreel inspect`: what it prints of a recording."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest
from support.maniskill_files import copy_recording, record_maniskill

from simreel.cli.main import main


def test_inspect_file_without_frequencies(tmp_path, capsys):
    from simreel.formats import open_writer
    from simreel.model.meta import RecordingMeta

    open_writer(tmp_path / "api.h5", RecordingMeta(env_id="PickCube-v1")).close()
    assert main(["inspect", str(tmp_path / "api.h5")]) == 0
    assert "? Hz sim / ? Hz control" in capsys.readouterr().out


@pytest.fixture(scope="module")
def ms_dir(tmp_path_factory) -> Path:
    """A RecordEpisode file of PickCube-v1: 2 episodes of 6 steps, env states."""
    folder = tmp_path_factory.mktemp("maniskill")
    record_maniskill(folder, "PickCube-v1", name="demos", episodes=2, steps=6)
    return folder


def _off_by_one(path: Path, index: int) -> None:
    """Episode `index`'s first state made its second, as replay_trajectory --use-env-states writes it."""
    with h5py.File(path, "a") as f:
        states = f[f"traj_{index}/env_states"]
        states.visititems(lambda _, ds: ds.__setitem__(0, ds[1]) if isinstance(ds, h5py.Dataset) else None)


def _inspected(path: Path, capsys) -> tuple[str, list[dict]]:
    """inspect's text, and the episodes of inspect --json."""
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert main(["inspect", "--json", str(path)]) == 0
    return text, json.loads(capsys.readouterr().out)["episodes"]


def test_quirks_only_an_episodes_data_shows_are_named(ms_dir, tmp_path, capsys):
    """The first state off by one (found in state rows 0 and 1), and an episode every command refuses, are named
    per episode as replay names them, not only the quirks of the listing."""
    path = copy_recording(ms_dir, "demos", tmp_path)
    _off_by_one(path, 1)
    text, episodes = _inspected(path, capsys)
    assert [e["initial_state_known"] for e in episodes] == [True, False]
    assert "as in files replay_trajectory writes with --use-env-states" in episodes[1]["notes"][0]
    assert "note: env_states[0] and env_states[1] agree within restore noise" in text
    with h5py.File(path, "a") as f:
        del f["traj_1/rewards"]
    text, episodes = _inspected(path, capsys)
    assert episodes[1]["notes"] == ["refused when read: traj_1 differs from traj_0 (the first episode, whose datasets "
                                    "set the file's layout): it lacks rewards"]
    assert "note: refused when read: traj_1 differs from traj_0" in text


def test_only_the_first_episodes_are_opened_and_it_says_so(ms_dir, tmp_path, capsys, monkeypatch):
    """Opening reads data: inspect opens the first `OPENED_EPISODES` only (a file of thousands stays fast) and says
    how many of how many it opened."""
    monkeypatch.setattr("simreel.cli.inspect.OPENED_EPISODES", 1)
    path = copy_recording(ms_dir, "demos", tmp_path)
    _off_by_one(path, 0)
    _off_by_one(path, 1)
    text, episodes = _inspected(path, capsys)
    assert [e["initial_state_known"] for e in episodes] == [False, True]
    assert ("note: the first 1 of 2 episodes were opened for what only their data shows (a first state off by one, "
            "an episode every command refuses); `simreel replay` opens every one\n") in text


def test_a_file_that_names_no_reward_mode_shows_the_one_the_env_used(ms_dir, capsys):
    """A RecordEpisode file made without reward_mode showed reward=None, though it holds rewards and replay compares
    them: ManiSkill used the task's default."""
    assert main(["inspect", str(ms_dir / "demos.h5")]) == 0
    out = capsys.readouterr().out
    assert "reward=normalized_dense (the task's default: the file names none; rewards recorded)" in out
    assert "reward=None" not in out


def test_inspect_counts_unseeded_episodes_and_those_with_generator_states(tmp_path, capsys):
    """simreel's RecordWrapper keeps the generator states of an unseeded reset (a replay remakes it); ManiSkill's
    RecordEpisode does not (a replay starts from the recorded initial state): inspect says how many of each."""
    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    ours = tmp_path / "ours.h5"
    rec = RecordWrapper(make_env("PickCube-v1", render_backend="none"), ours)
    for seed in (0, None, None):
        rec.reset(seed=seed)
        rec.step(rec.action_space.sample())
    rec.close()
    theirs = record_maniskill(tmp_path, "PickCube-v1", name="theirs", episodes=3, steps=2, seeded=False)
    capsys.readouterr()
    assert main(["inspect", str(ours)]) == 0
    assert ("unseeded: 2 episode(s) reset without a seed; 2 with their random generators' states (a replay remakes "
            "their reset), 0 without") in capsys.readouterr().out
    assert main(["inspect", str(theirs)]) == 0
    assert ("unseeded: 2 episode(s) reset without a seed; 0 with their random generators' states (a replay remakes "
            "their reset), 2 without (a replay starts them from their recorded initial state: not exact; 2 with a seed "
            "the file gives that may be stale, kept where it remakes that state)") in capsys.readouterr().out
    assert main(["inspect", "--json", str(ours)]) == 0
    assert json.loads(capsys.readouterr().out)["unseeded"] == {"episodes": 2, "with_generators": 2}
