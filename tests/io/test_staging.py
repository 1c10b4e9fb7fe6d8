"""Where a writer writes (`simreel.io.staging`): a second writer of a file being recorded is refused, and
`--overwrite` replaces an old recording only once the new one is complete — with real recording processes."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys

import pytest
from support.children import RecordingChild
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.errors import UsageError
from simreel.formats import check_writable, open_reader, open_writer
from simreel.io.staging import is_staging_path, side_folder, staging_path, stale_staging


def simreel(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_a_second_recorder_with_overwrite_is_refused_and_the_first_keeps_its_file(tmp_path, suffix):
    """Regression (HDF5): `record --overwrite` on a file another process was recording deleted it, the first
    recorder went on committing into the second's file, both exited 0 and the file mixed two recordings."""
    path = tmp_path / f"live{suffix}"
    with RecordingChild(str(path), "--steps", "10") as first:
        first.wait_committed(2)
        second = simreel("record", "PushCube-v1", "-o", str(path), "--overwrite", "--max-steps", "2", "-q")
        assert second.returncode == 2
        assert second.stderr == (f"simreel record: error: {path} is being written by another recording; choose another "
                                 "file, or wait until that recording has finished\n")
        first.wait_committed(first.committed + 2)  # still recording, into its own file
        assert first.signal(signal.SIGTERM) != 0
    if suffix == ".mcap":
        assert simreel("recover", str(path)).returncode == 0
    with open_reader(path) as r:
        assert r.meta.env_id == "PickCube-v1" and "PushCube" not in r.meta.command
        assert [m.index for m in r.episodes] == list(range(len(r.episodes))) and len(r.episodes) >= 4
        for m in r.episodes:
            assert r.read_episode(m.index).length == 10


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_overwrite_keeps_the_old_recording_until_the_new_one_is_complete(tmp_path, suffix):
    path = tmp_path / f"rec{suffix}"
    meta = synthetic_meta()
    write(path, meta, [synthetic_episode(meta, 0, 5)])
    old = path.read_bytes()
    with RecordingChild(str(path), "--overwrite", "--steps", "10") as new:
        new.wait_committed(2)
        with open_reader(path) as r:  # while the new one is recorded, the old one is there, whole
            assert r.meta.env_id == "Synthetic-v0" and len(r.episodes) == 1
            assert r.notes == [f"a recording that will replace this one when it is complete is being written in "
                               f"{side_folder(path) / path.name}"]
        assert new.signal(signal.SIGKILL) == -signal.SIGKILL
    assert path.read_bytes() == old  # killed before it was complete: the old recording is untouched
    staged = staged_left = side_folder(path) / path.name
    with open_reader(path) as r:
        assert r.notes == [f"a recording that was to replace this one stopped before it was complete; its committed "
                           f"episodes are in {staged} (this file is unchanged)"]
    inspect = simreel("inspect", str(path))
    assert inspect.returncode == 0 and f"its committed episodes are in {staged}" in inspect.stdout
    if suffix == ".mcap":
        assert simreel("recover", str(staged), "-o", str(tmp_path / "saved.mcap")).returncode == 0
        staged = tmp_path / "saved.mcap"
    with open_reader(staged) as r:
        assert r.meta.env_id == "PickCube-v1" and len(r.episodes) >= 2

    with pytest.raises(UsageError, match=f"{staged_left} holds the episodes of a recording that stopped before it "
                                         "was complete; move it out of"):
        check_writable(path, overwrite=True)  # --overwrite replaces the old recording, never the kept one
    shutil.rmtree(side_folder(path))  # the user has what they wanted of it
    with RecordingChild(str(path), "--overwrite", "--steps", "10", "--episodes", "3") as complete:
        assert complete.wait() == 0
    with open_reader(path) as r:  # complete: it has replaced the old one, and nothing is left beside it
        assert r.meta.env_id == "PickCube-v1" and len(r.episodes) == 3 and r.notes == []
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != "saved.mcap") == sorted(
        [path.name] + ([path.with_suffix(".json").name] if suffix == ".h5" else []))


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_a_writer_refuses_a_file_another_writer_holds_in_this_process_too(tmp_path, suffix):
    meta = synthetic_meta()
    path = tmp_path / f"live{suffix}"
    with open_writer(path, meta) as w:
        w.write_episode(synthetic_episode(meta, 0, 3))
        with pytest.raises(UsageError, match="is being written by another recording"):
            open_writer(path, meta, overwrite=True)
    with open_reader(path) as r:
        assert len(r.episodes) == 1


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_a_copy_that_fails_keeps_the_output_it_was_to_replace(tmp_path, suffix):
    """`convert --overwrite` that fails half way drops what it wrote; the old OUT stays as it was."""
    from simreel.datasets.copy import convert

    meta = synthetic_meta()
    src = write(tmp_path / "src.h5", meta, [synthetic_episode(meta, i, 4) for i in range(3)])
    out = write(tmp_path / f"out{suffix}", meta, [synthetic_episode(meta, 7, 2)])
    before = out.read_bytes()

    def fail_on_the_second(episode):
        if episode.meta.index == 1:
            raise RuntimeError("boom")
        return episode

    class Failing:
        def __init__(self, m):
            self.meta = m

        def __call__(self, episode):
            return fail_on_the_second(episode)

        def close(self):
            pass

    with pytest.raises(RuntimeError, match="boom"):
        convert(src, out, overwrite=True, transform=Failing)
    assert out.read_bytes() == before and not side_folder(out).exists()


def test_a_signal_while_a_staged_hdf5_is_published_never_pairs_it_with_the_old_sidecar(record, tmp_path, monkeypatch):
    """`convert --overwrite` to .h5 moved the new OUT.h5 into place, then its sidecar OUT.json: a SIGTERM between the
    two moves left the new recording beside the old sidecar (other episodes and seeds, which ManiSkill's loader
    reads). The signal is sent from inside the first move, the moment it can land in a real run."""
    import json
    import os

    from simreel.cli.main import main

    old, new = record("PickCube-v1", 2, 5), record("PickCube-v1", 3, 5)
    out = tmp_path / "OUT.h5"
    shutil.copy(old, out)
    shutil.copy(old.with_suffix(".json"), tmp_path / "OUT.json")
    real_replace, moves = os.replace, []

    def replace_then_signal(src, dst, *args, **kwargs):
        real_replace(src, dst, *args, **kwargs)
        if os.path.dirname(dst) == str(tmp_path) and os.path.basename(dst) in ("OUT.h5", "OUT.json"):  # a final name
            moves.append(os.path.basename(dst))
            if len(moves) == 1:
                os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(os, "replace", replace_then_signal)
    code = main(["convert", str(new), str(out), "--overwrite", "-q"])
    monkeypatch.undo()
    assert code == 143 and sorted(moves) == ["OUT.h5", "OUT.json"]
    with open_reader(out) as r:
        held = [(m.index, m.seed) for m in r.episodes]
    listed = [(e["episode_id"], e["episode_seed"]) for e in json.loads((tmp_path / "OUT.json").read_text())["episodes"]]
    assert held == listed and len(held) == 3


def test_the_staging_name_of_a_long_output_name_is_one_the_file_system_takes(tmp_path):
    """Merge and filter write OUT under ``.OUT.simreel-PID@HOST.h5``, longer than OUT by the process tag: a stem
    past `short_name`'s length is cut and digested there, as temporary files' are, and is still known as OUT's."""
    final = tmp_path / ("y" * 240 + ".h5")
    staged = staging_path(final)
    assert len(staged.name.encode()) <= 200 and staged.parent == tmp_path and is_staging_path(staged)
    assert staging_path(final) == staged and staging_path(final.with_name("y" * 239 + "z.h5")) != staged
    staged.write_bytes(b"")
    assert stale_staging(final) == []  # this process's own: never stale while it lives
