"""`view --compare OTHER` says what OTHER is, whatever it is: a `simreel replay -o` output of the recording is the
replay, any other recording of the task (a second `simreel record` run, a ManiSkill RecordEpisode file) is named by
its file, never called a replay. The ghost is always under `compared/`. Real recordings, real replays, the .rrd read
back with rerun's own reader."""

from __future__ import annotations

import pytest

from simreel.cli.main import main

STEPS = 10


def _record(path, seed):
    assert main(["record", "PickCube-v1", "-o", str(path), "-n", "1", "--max-steps", str(STEPS), "--seed", str(seed),
                 "--render-backend", "none", "-q"]) == 0
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return _record(tmp_path_factory.mktemp("names") / "rec.h5", 3)


def _view(recording, other, out, capsys, rrd_reader):
    """`simreel view recording --compare other --save out`: (stdout lines, entity paths, events' texts)."""
    capsys.readouterr()
    assert main(["view", str(recording), "--compare", str(other), "--save", str(out), "--geometry", "collision"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rrd = rrd_reader(out)
    events = [text[0] for _, text in rrd.data["/events"]["TextLog:text"]]
    return lines, set(rrd.data), events


def _ghost_is_under_compared(entities):
    assert {"/compared/cube", "/compared/panda/panda_hand"} <= entities, sorted(entities)
    assert not any(e.startswith("/replayed") for e in entities)


def test_a_replay_of_the_recording_is_the_replay(recording, tmp_path, capsys, rrd_reader):
    replayed = tmp_path / "replayed.h5"
    assert main(["replay", str(recording), "-o", str(replayed), "-q"]) == 0
    lines, entities, events = _view(recording, replayed, tmp_path / "r.rrd", capsys, rrd_reader)
    _ghost_is_under_compared(entities)
    assert "compared with replayed.h5 episode 0 (replay): exact" in events
    assert "replay exact: no value leaves its tolerance" in lines


def _second_recording(folder):
    return _record(folder / "second.h5", 4)


def _maniskill_file(folder):
    from support.maniskill_files import record_maniskill

    return record_maniskill(folder, "PickCube-v1", name="second", episodes=1, steps=STEPS)


@pytest.mark.parametrize("make", [_second_recording, _maniskill_file], ids=["simreel-record", "maniskill"])
def test_another_recording_is_named_by_its_file_never_called_a_replay(recording, tmp_path, capsys, rrd_reader, make):
    """Before: its ghost under `replayed/`, "compared with second.h5 episode 0 (replayed)", "replay diverges after
    reset: ..." in the events and on stdout, and "the replayed file holds no explanation"."""
    other = make(tmp_path)
    lines, entities, events = _view(recording, other, tmp_path / "o.rrd", capsys, rrd_reader)
    _ghost_is_under_compared(entities)
    assert "compared with second.h5 episode 0: diverged" in events
    assert any(e.startswith("second.h5 diverges after reset: env_states/") for e in events), events
    assert any(line.startswith("second.h5 diverges after reset: env_states/") for line in lines), lines
    assert not any("replayed" in text or text.startswith("replay ") for text in events + lines), events + lines
    assert ("why: cause not classified: the compared file is no replay of this recording (`simreel replay -o` "
            "classifies the cause of its replays' divergences)") in events
