"""`simreel recover` on a real HDF5 recording with damaged episodes: it keeps every intact one and names the others."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
from support.children import simreel
from support.damage import stored_bytes
from support.mcap_samples import assert_same_episode, synthetic_episode, synthetic_meta, write

from simreel.cli.main import main
from simreel.formats import open_reader


def test_recover_keeps_every_intact_hdf5_episode_and_names_the_damaged_ones(record, tmp_path):
    """Issue 17, item 6 (HDF5): one damaged episode must not cost the intact ones after it. Episode 1's stored
    bytes fail their checksum; episode 2 lacks a dataset its layout lists; 0, 3 and 4 must come out unchanged."""
    path = tmp_path / "damaged.h5"
    path.write_bytes(record("PickCube-v1", 5, 12).read_bytes())
    with open_reader(path) as r:
        intact = {i: r.read_episode(i) for i in (0, 3, 4)}
    offset, size = stored_bytes(path, "traj_1/env_states/articulations/panda")
    data = bytearray(path.read_bytes())
    data[offset + size // 2] ^= 0x04
    path.write_bytes(data)
    with h5py.File(path, "a") as f:
        del f["traj_2/contact_forces"]

    done = simreel("recover", str(path), "-o", str(tmp_path / "saved.h5"))

    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == f"recovered 3 committed episode(s), 36 steps, into {tmp_path / 'saved.h5'}"
    lost = next(line for line in lines if line.startswith("lost (damaged): "))
    assert "episode 1 (traj_1/env_states/articulations/panda is corrupt: its data fails its checksum" in lost
    assert "episode 2 (traj_2 lacks contact_forces, which the recording's layout lists)" in lost
    with open_reader(tmp_path / "saved.h5") as r:
        assert [m.index for m in r.episodes] == [0, 3, 4] and r.damaged == [] and r.unfinished == []
        for i, want in intact.items():
            assert_same_episode(r.read_episode(i), want)
    sidecar = json.loads((tmp_path / "saved.json").read_text())  # what ManiSkill's tools read beside the .h5
    assert [e["episode_id"] for e in sidecar["episodes"]] == [0, 3, 4]
    with open_reader(path) as r:  # the damaged input is left as it was
        assert [m.index for m in r.episodes] == [0, 1, 2, 3, 4]


def test_a_maniskill_file_is_recovered_with_o_only_and_stays_as_it_was(tmp_path):
    """In place, `recover` would rewrite a RecordEpisode file as a simreel recording: its sidecar's own fields and a
    group its sidecar does not list (one a killed RecordEpisode left) would be gone. Refused, nothing touched; with
    -o the file and its sidecar stay byte for byte."""
    from support.maniskill_files import record_maniskill

    path = record_maniskill(tmp_path, "PickCube-v1", episodes=2, steps=8)
    with h5py.File(path, "a") as f:
        f.copy("traj_0", "traj_7")  # written, never listed
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    refused = simreel("recover", str(path))
    assert refused.returncode == 2 and refused.stderr == (
        f"simreel recover: error: {path} is a ManiSkill file (RecordEpisode's): recovering it in place would replace it "
        "by a simreel recording, losing its sidecar's own fields and any group the sidecar does not list; recover it "
        "with -o\n")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before

    done = simreel("recover", str(path), "-o", str(tmp_path / "saved.h5"))
    assert done.returncode == 0, done.stderr
    assert "found: 1 group(s) the sidecar does not list (traj_7)" in done.stdout
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name in before} == before
    with open_reader(tmp_path / "saved.h5") as r:
        assert [m.index for m in r.episodes] == [0, 1]


def test_a_simreel_recording_made_from_a_maniskill_file_is_recovered_in_place(tmp_path):
    """Only a ManiSkill file itself is refused in place: a simreel recording converted from one (its metadata keeps
    where it came from) is recovered as any other. Its damage is in one chunk's data, which only reading finds:
    recover reads every episode through before it calls a file complete (it used to say "nothing to recover")."""
    from support.damage import corrupt_chunk
    from support.maniskill_files import record_maniskill

    converted = tmp_path / "converted.h5"
    assert simreel("convert", str(record_maniskill(tmp_path, "PickCube-v1", episodes=3, steps=12)), str(converted),
                   "-q").returncode == 0
    corrupt_chunk(converted, "traj_1/actions", 1)
    done = simreel("recover", str(converted))
    assert done.returncode == 0, done.stderr
    with open_reader(converted) as r:
        assert [m.index for m in r.episodes] == [0, 2] and r.meta.source["format"] == "maniskill"


def test_the_hint_for_a_damaged_maniskill_episode_is_a_recover_that_works(tmp_path):
    """Regression: the hint said `simreel recover demos.h5`, which refuses a ManiSkill file without -o."""
    import shlex

    from support.maniskill_files import record_maniskill

    path = record_maniskill(tmp_path, "PickCube-v1", episodes=2, steps=5)
    with h5py.File(path, "a") as f:
        del f["traj_1/actions"]
    copy = tmp_path / "demos.recovered.h5"
    refused = simreel("view", str(path), "--episode", "1", "--save", str(tmp_path / "v.rrd"))
    assert refused.returncode == 2, refused.stderr
    hint = f"`simreel recover {path} -o {copy}` copies its intact episodes (a ManiSkill file is recovered with -o)"
    assert refused.stderr.count("\n") == 1 and refused.stderr.endswith(f"; {hint}\n"), refused.stderr
    done = simreel(*shlex.split(hint.split("`")[1])[1:])
    assert done.returncode == 0, done.stderr
    with open_reader(copy) as r:
        assert [m.index for m in r.episodes] == [0]


SUPPORT = Path(__file__).resolve().parents[1] / "support"


@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGINT, signal.SIGTERM], ids=["kill-9", "ctrl-c", "sigterm"])
def test_an_interrupted_in_place_recovery_keeps_the_journal_of_the_lost_episode(tmp_path, stop):
    """`recover X.h5` in place writes the recovered file under a hidden staging name and touches X.h5.partial/ (the
    journal naming the killed recording's running episode, its streamed scratch file) only once the recovered file
    has replaced X.h5: interrupted while it copies, X.h5 and the record of the lost episode stay as they were (it
    once removed them first, and a recovery run after said nothing was lost)."""
    meta = synthetic_meta()
    path = write(tmp_path / "rec.h5", meta, [synthetic_episode(meta, i, 4) for i in range(3)])
    partial = tmp_path / "rec.h5.partial"
    partial.mkdir()
    (partial / "running.jsonl").write_text('{"began": 3, "env_idx": 0, "seed": 3}\n')
    write(partial / "traj_3.h5", meta, [synthetic_episode(meta, 3, 2)])  # a scratch file of 2 steps
    before = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    child = subprocess.Popen([sys.executable, str(SUPPORT / "paused_copy.py"), "recover", str(path)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "copying"
        child.send_signal(stop)
        child.communicate(timeout=60)
    finally:
        child.kill()
    assert child.returncode == {signal.SIGKILL: -9, signal.SIGINT: 130, signal.SIGTERM: 143}[stop]
    after = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*")
             if p.is_file() and not p.relative_to(tmp_path).parts[0].startswith(".")}
    assert after == before
    done = simreel("recover", str(path))
    assert done.returncode == 0, done.stderr
    assert "episode 3" in done.stdout and not partial.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0, 1, 2] and r.unfinished == []


def test_an_in_place_recovery_the_disk_cannot_hold_keeps_the_journal_of_the_lost_episode(tmp_path, capsys):
    """A full disk stops `recover X.h5` in place while it copies: one line, exit 2, and X.h5 with X.h5.partial/ (the
    journal of the killed recording's lost episode) as they were."""
    from support.mcap_samples import long_sample
    from support.small_disk import fill, small_disk

    long, _ = long_sample(tmp_path / "long.h5")
    with small_disk(tmp_path, 6 << 10) as disk:
        path = disk / "rec.h5"
        path.write_bytes(long.read_bytes())
        partial = disk / "rec.h5.partial"
        partial.mkdir()
        (partial / "running.jsonl").write_text('{"began": 9, "env_idx": 0, "seed": 9}\n')
        before = {p.relative_to(disk): p.read_bytes() for p in disk.rglob("*") if p.is_file()}
        fill(disk, 256)  # room for a few episodes of the copy, not all of them
        assert main(["recover", str(path)]) == 2
        [line] = capsys.readouterr().err.splitlines()
        assert line.startswith(f"simreel recover: error: {path}: the disk is full"), line
        after = {p.relative_to(disk): p.read_bytes() for p in disk.rglob("*") if p.is_file()
                 and not p.name.startswith("filler")}
        assert after == before
