"""`simreel merge`: the summary (per input, what was checked), one-line refusals (exit 2), progress bars only on a
terminal, and Ctrl-C leaving no half-written output (a real process and signal)."""

from __future__ import annotations

import io
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from support.maniskill_files import copy_recording, edit_sidecar, record_maniskill
from support.mcap_samples import long_sample, synthetic_episode, synthetic_meta, write

from simreel.cli.main import main
from simreel.formats import open_reader, recording_files

SUPPORT = Path(__file__).resolve().parents[1] / "support"


@pytest.fixture()
def inputs(tmp_path) -> list[Path]:
    meta = synthetic_meta()
    a = write(tmp_path / "a.h5", meta, [synthetic_episode(meta, i, T) for i, T in enumerate((4, 70, 1))])
    b = write(tmp_path / "b.mcap", meta, [synthetic_episode(meta, i, T, seed=5) for i, T in enumerate((6, 2))])
    return [a, b]


def test_merge_prints_where_each_input_went_and_what_was_checked(inputs, tmp_path, capsys):
    out = tmp_path / "all.mcap"
    assert main(["merge", *map(str, inputs), "-o", str(out), "-q"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"merged 2 file(s): 5 episode(s), 83 steps → {out} (")
    assert lines[1].split() == ["a.h5", "3", "episode(s)", "→", "episodes", "0-2"]
    assert lines[2].split() == ["b.mcap", "2", "episode(s)", "→", "episodes", "3-4"]
    assert lines[3] == "checked: 5 episodes, every array equal to its source"
    with open_reader(out) as r:
        assert r.meta.command == f"simreel merge {inputs[0]} {inputs[1]} -o {out} -q"


def test_inspect_shows_the_provenance_and_each_episodes_origin(inputs, tmp_path, capsys):
    out = tmp_path / "all.h5"
    assert main(["merge", *map(str, inputs), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "  made by    merge of a.h5 (3 episode(s)), b.mcap (2 episode(s))\n" in text
    rows = [line.split() for line in text.splitlines() if line.strip().startswith(("0 ", "3 "))]
    assert rows[0][:6] == ["0", "0", "100", "4", "False", "a.h5#0"] and rows[1][5] == "b.mcap#0"


def test_progress_bars_count_the_copy_and_the_check_on_a_terminal_only(inputs, tmp_path, capsys, monkeypatch):
    assert main(["merge", *map(str, inputs), "-o", str(tmp_path / "piped.h5")]) == 0
    assert capsys.readouterr().err == ""  # not a terminal: no bar

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    assert main(["merge", *map(str, inputs), "-o", str(tmp_path / "shown.h5")]) == 0
    bars = sys.stderr.getvalue()
    assert "merge: 100%" in bars and "check shown.h5: 100%" in bars and "5/5" in bars


def test_different_envs_are_one_line_and_exit_2(inputs, tmp_path, capsys):
    import dataclasses

    other = dataclasses.replace(synthetic_meta(), control_mode="pd_joint_pos")
    c = write(tmp_path / "c.h5", other, [synthetic_episode(other, 0, 3)])
    assert main(["merge", str(inputs[0]), str(c), "-o", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err
    assert err == (f"simreel merge: error: {c} records another env than {inputs[0]}: control_mode is 'pd_joint_pos' "
                   f"there, None in {inputs[0]}; only recordings of one env (same settings, layouts and simulator "
                   "versions) become one file\n")
    assert not (tmp_path / "out.h5").exists()


@pytest.fixture(scope="module")
def ms_dir(tmp_path_factory) -> Path:
    """RecordEpisode files of PickCube-v1 (pd_joint_pos, no observations): with rewards, and without."""
    folder = tmp_path_factory.mktemp("maniskill")
    record_maniskill(folder, "PickCube-v1", name="plain", episodes=2, steps=6)
    record_maniskill(folder, "PickCube-v1", name="noreward", episodes=1, steps=6, record_reward=False)
    return folder


def test_a_long_value_that_differs_is_shown_where_it_differs(ms_dir, tmp_path, capsys):
    """Long lists are not cut to the same first characters (which never showed the difference): what one holds and
    the other lacks."""
    plain, noreward = ms_dir / "plain.h5", ms_dir / "noreward.h5"
    assert main(["merge", str(plain), str(noreward), "-o", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err
    assert f"records another env than {plain}: unknown holds ['rewards'] there, not in {plain};" in err
    assert err.count("\n") == 1


def test_a_render_mode_of_replay_trajectory_does_not_keep_files_apart_and_the_merge_replays(ms_dir, tmp_path, capsys):
    """ManiSkill's replay_trajectory writes ``render_mode: rgb_array`` into every file it makes; it changes neither
    the physics nor the arrays, so such a file merges with a RecordEpisode one: the output records no render_mode
    (the inputs give none in common), says so, and replays verified."""
    rendered = copy_recording(ms_dir, "plain", tmp_path)
    edit_sidecar(rendered, lambda doc: doc["env_info"]["env_kwargs"].update(render_mode="rgb_array"))
    out = tmp_path / "out.h5"
    assert main(["merge", str(ms_dir / "plain.h5"), str(rendered), "-o", str(out), "-q"]) == 0
    assert (f"note: render_mode differs between the inputs (none in {ms_dir / 'plain.h5'}; 'rgb_array' in "
            f"{rendered}); it changes neither the physics nor the arrays, and the output records none\n"
            ) in capsys.readouterr().out
    with open_reader(out) as r:
        assert "render_mode" not in r.meta.env_kwargs and len(r.episodes) == 4
    assert main(["replay", str(out), "-q"]) == 0
    assert "4 of 4 episode(s) verified" in capsys.readouterr().out
    again = tmp_path / "again" / "plain.h5"
    again.parent.mkdir()
    copy_recording(tmp_path, "plain", again.parent)
    assert main(["merge", str(rendered), str(again), "-o", str(tmp_path / "both.h5"), "-q"]) == 0
    assert "note:" not in capsys.readouterr().out
    with open_reader(tmp_path / "both.h5") as r:
        assert r.meta.env_kwargs["render_mode"] == "rgb_array"  # the value every input gives is kept


def test_overwrite_replaces_out(inputs, tmp_path):
    out = tmp_path / "out.h5"
    out.write_bytes(b"old")
    assert main(["merge", *map(str, inputs), "-o", str(out), "--overwrite", "-q"]) == 0
    with open_reader(out) as r:
        assert len(r) == 5


@pytest.mark.parametrize("existing", [False, True], ids=["new-out", "overwrite"])
def test_ctrl_c_during_the_copy_leaves_no_output_and_the_inputs_as_they_were(inputs, tmp_path, existing):
    """OUT is written under a hidden staging name beside it and moved into place once checked: an interrupted
    merge leaves neither a half-written OUT nor its staging files, and with --overwrite the old OUT stays."""
    out = tmp_path / "out.h5"
    if existing:
        out.write_bytes(b"the old OUT")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    child = subprocess.Popen([sys.executable, str(SUPPORT / "paused_copy.py"), "merge", *map(str, inputs), "-o", str(out),
                              *(["--overwrite"] if existing else [])],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "copying"
        staged = [p.name for p in tmp_path.iterdir() if p.name.startswith(".out.simreel-")]
        assert f".out.simreel-{child.pid}@{socket.gethostname()}.h5" in staged  # two episodes are in it by now
        child.send_signal(signal.SIGINT)
        _, err = child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == 130 and err == "simreel merge: interrupted\n"
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    assert [p for p in recording_files(out) if p.exists()] == ([out] if existing else [])


def test_two_merges_to_one_new_out_keep_the_first_and_refuse_the_second_in_one_line(inputs, tmp_path):
    """The first merge passes the start's check (OUT does not exist yet) and is paused in its copy; a second one
    writes OUT meanwhile; the first then finds OUT made and leaves it as it is: exit 2 and one line, never an
    internal error or a replaced OUT."""
    out = tmp_path / "m.h5"
    first = subprocess.Popen([sys.executable, str(SUPPORT / "paused_copy.py"), "merge", *map(str, inputs), "-o", str(out)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert first.stdout.readline().strip() == "copying"
        assert main(["merge", str(inputs[1]), "-o", str(out), "-q"]) == 0
        _, err = first.communicate("go on\n", timeout=120)
    finally:
        first.kill()
    assert first.returncode == 2 and err == (f"simreel merge: error: {out} was written by another command while this "
                                             "one ran (m.json is there now); it is left as it is and nothing was written "
                                             "(pass --overwrite to replace it (overwrite=True from Python))\n")
    with open_reader(out) as r:
        assert [m.origin.file for m in r.episodes] == [str(inputs[1])] * 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "a.json", "b.mcap", "m.h5", "m.json"]


def test_overwrite_replaces_a_recording_and_every_file_beside_it(inputs, tmp_path):
    out = tmp_path / "out.h5"
    (tmp_path / "out.json").write_text("old sidecar")
    (tmp_path / "out.h5.partial").mkdir()
    (tmp_path / "out.h5.partial" / "traj_9.h5").write_bytes(b"scratch of a killed recording")
    assert main(["merge", *map(str, inputs), "-o", str(out), "--overwrite", "-q"]) == 0
    assert not (tmp_path / "out.h5.partial").exists() and "episode_id" in (tmp_path / "out.json").read_text()
    with open_reader(out) as r:
        assert len(r) == 5 and r.unfinished == []
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_an_episode_a_killed_recording_left_uncommitted_is_named_and_not_copied(inputs, tmp_path, capsys):
    """A killed HDF5 recording leaves its running episode's scratch file in NAME.h5.partial/: that episode was
    never committed, so it is not in the merge, and the summary says so (as convert warns)."""
    (tmp_path / "a.h5.partial").mkdir()
    (tmp_path / "a.h5.partial" / "traj_3.h5").write_bytes(b"")
    assert main(["merge", *map(str, inputs), "-o", str(tmp_path / "out.h5"), "-q"]) == 0
    out = capsys.readouterr().out
    assert (f"note: {inputs[0]}: episode 3 (a scratch file, ? step(s)) was never committed (a killed recording) "
            "and is not copied\n") in out  # an empty scratch file: its steps cannot be counted
    assert "merged 2 file(s): 5 episode(s)" in out


def test_a_block_that_fails_its_checksum_mid_episode_leaves_no_output(inputs, tmp_path, capsys):
    """An input episode damaged in its third block of rows, after two were copied: one line naming the damage,
    exit 2, and neither OUT nor its staging files left."""
    from support.damage import corrupt_chunk

    src, _ = long_sample(tmp_path / "long.h5")
    corrupt_chunk(src, "traj_1/actions", chunk=8, rows=1000)  # rows 8000-8999
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["merge", str(inputs[0]), str(src), "-o", str(tmp_path / "out.mcap"), "-q"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"simreel merge: error: {src}: ") and "traj_1/actions" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("command", ["merge", "filter"])
def test_an_output_of_a_long_name_the_file_system_takes_is_written(inputs, tmp_path, capsys, command):
    """A 240-byte OUT (of 255 allowed) is written as `convert` and `record` write it: the hidden name it is staged
    under (``.OUT.simreel-PID@HOST.h5``, longer by the process tag) is cut and digested as temporary files' names
    are, never past the file system's limit; nothing of it is left beside OUT."""
    out = tmp_path / ("y" * 240 + ".h5")
    args = [str(inputs[0]), "-o", str(out), "-q"] + (["--episodes", "0,2"] if command == "filter" else [])
    assert main([command, *args]) == 0, capsys.readouterr().err
    with open_reader(out) as r:
        assert len(r) == (2 if command == "filter" else 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a.h5", "a.json", "b.mcap", out.name,
                                                                 out.with_suffix(".json").name])


def test_a_hard_link_of_an_input_is_the_same_input_given_twice(inputs, tmp_path, capsys):
    """`merge a.h5 h.h5` where h.h5 is a hard link of a.h5 merged a.h5's episodes twice (exit 0); one file under two
    names is refused as a symbolic link or a `./` spelling of it is: by its device and inode."""
    hard = tmp_path / "h.h5"
    hard.hardlink_to(inputs[0])
    assert main(["merge", str(inputs[0]), str(hard), "-o", str(tmp_path / "out.h5"), "-q"]) == 2
    assert capsys.readouterr().err == f"simreel merge: error: {hard} is given twice; each input is merged once\n"
    assert not (tmp_path / "out.h5").exists()
