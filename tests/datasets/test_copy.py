"""`recover` (`simreel.datasets.copy`): it skips a damaged record, keeps going and names what it lost."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from support.mcap_samples import assert_same_episode, long_sample, synthetic_episode, synthetic_meta, write

from simreel.datasets.copy import recover
from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.formats.mcap.blocks import HEADER


def _killed(tmp_path: Path, n: int = 5) -> tuple[Path, list, bytearray]:
    """An MCAP file of `n` episodes as a killed recording leaves it (no summary, no footer)."""
    meta = synthetic_meta(poses=False)
    episodes = [synthetic_episode(meta, i, 8) for i in range(n)]
    path = write(tmp_path / "rec.mcap", meta, episodes, compression="none")
    data = bytearray(path.read_bytes())
    _, _, summary_start, _, _ = struct.unpack("<BQQQI", data[-8 - 29 : -8])
    return path, episodes, data[: summary_start - 13]  # cut before DataEnd


def _record_start(data: bytearray, inside: int) -> int:
    """Walk the records from the start to the one that contains byte `inside`."""
    pos = 8
    while True:
        _, length = struct.unpack_from("<BQ", data, pos)
        if pos + 9 + length > inside:
            return pos
        pos += 9 + length


def test_recover_skips_a_damaged_chunk_and_keeps_every_later_episode(tmp_path):
    """Regression: `recover` dropped every intact episode after one damaged record without naming them."""
    path, episodes, data = _killed(tmp_path)
    block = data.index(HEADER.pack(1, 0, 8))
    data[block + 30] ^= 0x01  # inside episode 1's chunk: it fails its CRC
    path.write_bytes(data)
    report = recover(path, tmp_path / "saved.mcap")
    assert (report.episodes, report.steps) == (4, 32)
    assert len(report.damaged) == 2
    assert report.damaged[0].startswith("bytes ") and report.damaged[0].endswith("(a damaged record)")
    assert report.damaged[1].startswith("episode 1 (episode 1: ")  # its steps were in the damaged chunk
    with open_reader(tmp_path / "saved.mcap") as r:
        assert [m.index for m in r.episodes] == [0, 2, 3, 4]
        for m in r.episodes:
            assert_same_episode(r.read_episode(m.index), episodes[m.index])


def test_recover_finds_the_next_whole_record_after_a_damaged_record_length(tmp_path, capsys):
    path, episodes, data = _killed(tmp_path)
    chunk = _record_start(data, data.index(HEADER.pack(2, 0, 8)))
    struct.pack_into("<Q", data, chunk + 1, 10**12)  # its length now points far past the end of the file
    path.write_bytes(data)
    from simreel.cli.main import main

    assert main(["recover", str(path)]) == 0  # in place
    out = capsys.readouterr().out
    assert "recovered 4 committed episode(s), 32 steps" in out
    assert "lost (damaged): bytes " in out and "episode 2 (episode 2: " in out
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0, 1, 3, 4] and r.damaged == []
        assert_same_episode(r.read_episode(4), episodes[4])


def test_recover_of_a_complete_file_changes_nothing(tmp_path):
    meta = synthetic_meta(poses=False)
    for name in ("ok.mcap", "ok.h5"):
        path = write(tmp_path / name, meta, [synthetic_episode(meta, 0, 3)])
        before = path.read_bytes()
        report = recover(path)
        assert report.complete and report.output is None and path.read_bytes() == before


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_recover_finds_damage_in_a_late_block_before_writing_any_of_that_episode(tmp_path, suffix):
    """Episode 1 spans three blocks of rows and its third fails its checksum: recover names it lost and copies
    episodes 0 and 2, and nothing of episode 1 reaches the output (no rows, no discarded-episode record)."""
    from support.damage import corrupt_chunk

    src, episodes = long_sample(tmp_path / "src.h5")
    corrupt_chunk(src, "traj_1/actions", chunk=8, rows=1000)  # rows 8000-8999
    out = tmp_path / f"saved{suffix}"
    report = recover(src, out)
    assert (report.episodes, report.steps) == (2, 8)
    [lost] = report.damaged
    assert lost.startswith("episode 1 (") and "traj_1/actions" in lost
    with open_reader(out) as r:
        assert [m.index for m in r.episodes] == [0, 2] and r.damaged == [] and r.unfinished == [] and r.notes == []
        for i in (0, 2):
            assert_same_episode(r.read_episode(i), episodes[i])
    assert out.stat().st_size < 50_000  # episode 1's 9000 rows would be several MB


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # was: accepted as yes, and OUT was replaced
        (lambda src, out: recover(src, out, overwrite="no"), "overwrite='no': give True or False"),
        # was: TypeError expected str, bytes or os.PathLike object, not int
        (lambda src, out: recover(5), "path=5: give the recording to recover, a str or pathlib.Path"),
        (lambda src, out: recover(src, 5), "output=5: give the file to write, a str or pathlib.Path, or None (replace "
                                           "`path`)"),
        # was: ".: unknown recording suffix ''" (the working folder)
        (lambda src, out: recover(""), "an empty path names no recording (an unset shell variable?); name the "
                                       "recording to recover"),
        (lambda src, out: recover(src, ""), "an empty path names no recording (an unset shell variable?); name the "
                                            "file to write, or give None to recover in place"),
    ],
    ids=["overwrite-str", "path-int", "output-int", "path-empty", "output-empty"],
)
def test_recover_refuses_a_wrong_argument_before_writing_anything(record, tmp_path, call, message):
    src = record("PickCube-v1", 2, 5)
    before = src.read_bytes()
    out = tmp_path / "out.h5"
    out.write_text("an older file, to be kept")
    with pytest.raises(UsageError) as refused:
        call(src, out)
    assert str(refused.value) == message
    assert out.read_text() == "an older file, to be kept" and src.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5"]
