"""MCAP integrity: every CRC MCAP offers is written and checked, and a damaged episode is reported as corrupt, never
read as good data."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest
from support.children import SUPPORT, simreel
from support.mcap_samples import (
    assert_same_episode,
    only_this_episode_fails,
    sample,
)

from simreel.errors import RecordingFileError
from simreel.formats import open_reader
from simreel.formats.mcap.blocks import HEADER


def _sample(tmp_path: Path, n: int = 3, **options) -> tuple[Path, list]:
    return sample(tmp_path / "rec.mcap", n, **options)


def _footer(data: bytes) -> tuple[int, int]:
    """(summary start, footer offset) of a complete MCAP file."""
    footer = len(data) - 8 - 29
    _, _, summary_start, _, _ = struct.unpack("<BQQQI", data[footer : footer + 29])
    return summary_start, footer


def test_a_damaged_chunk_fails_its_crc_and_the_other_episodes_read(tmp_path):
    """Regression: chunk CRCs were written but never checked: a bit-flipped chunk that Python mcap, Rerun and the
    TypeScript reader reject was replayed "all verified". Uncompressed chunks, so the damage decodes."""
    path, episodes = _sample(tmp_path, compression="none")
    data = bytearray(path.read_bytes())
    block = data.index(HEADER.pack(1, 0, 6))  # episode 1's block of 6 steps
    data[block + 40] ^= 0x04
    path.write_bytes(data)
    err = only_this_episode_fails(path, episodes, 1)
    assert "episode 1: the chunk at byte" in str(err) and "CRC" in str(err)


def test_the_data_section_crc_is_written_and_checked(tmp_path):
    """Regression: the data section's CRC was written as 0. A damaged byte that nothing else covers (in the header
    record, which names the library that wrote the file) is found by `inspect`."""
    path, _ = _sample(tmp_path)
    data = bytearray(path.read_bytes())
    summary_start, _ = _footer(data)
    opcode, length, crc = struct.unpack("<BQI", data[summary_start - 13 : summary_start])
    assert opcode == 0x0F and length == 4 and crc != 0  # DataEnd with a CRC
    with open_reader(path) as r:
        assert r.check_data_crc() is None
    library = data.index(b"simreel ", 0, 64)  # the header record's library string
    data[library + 2] ^= 0x01
    path.write_bytes(data)
    done = simreel("inspect", str(path))
    assert done.returncode == 1
    assert "warning: damaged, not readable: its data section does not match its CRC: some bytes are damaged" in done.stdout


def test_a_damaged_summary_is_refused_and_recover_rebuilds_from_the_records(tmp_path):
    path, episodes = _sample(tmp_path)
    data = bytearray(path.read_bytes())
    summary_start, footer = _footer(data)
    data[(summary_start + footer) // 2] ^= 0x01
    path.write_bytes(data)
    with pytest.raises(RecordingFileError) as err:
        open_reader(path)
    assert str(err.value) == (f"{path}: corrupt MCAP file (its summary does not match its CRC); `simreel recover "
                              f"{path} -o OUT` copies the episodes that are intact")
    assert simreel("recover", str(path), "-o", str(tmp_path / "saved.mcap")).returncode == 0
    with open_reader(tmp_path / "saved.mcap") as r:
        for ep in episodes:
            assert_same_episode(r.read_episode(ep.meta.index), ep)


def test_a_damaged_episode_record_is_named_and_the_others_read(tmp_path):
    path, episodes = _sample(tmp_path)
    data = bytearray(path.read_bytes())
    record = data.index(b"simreel.episode.1")
    seed = data.index(b'"seed": 101', record)  # in the record's EpisodeMeta JSON
    data[seed + 10] = ord("7")  # seed 101 -> 107: valid JSON, the wrong number
    path.write_bytes(data)
    with open_reader(path) as r:
        assert [m.index for m in r.episodes] == [0, 2]
        assert r.damaged == ["record simreel.episode.1: the record does not match its checksum (damaged)"]
        assert_same_episode(r.read_episode(2), episodes[2])


@pytest.mark.slow  # minutes: thousands of damaged copies
@pytest.mark.parametrize("how", ["flip", "zero64"])
def test_no_damage_is_read_as_good_data_and_no_reader_hangs(tmp_path, how):
    path, _ = _sample(tmp_path, n=2)
    try:
        done = subprocess.run([sys.executable, str(SUPPORT / "damage.py"), str(path), how, "5"], capture_output=True,
                              text=True, timeout=900, cwd=SUPPORT.parent)
    except subprocess.TimeoutExpired as e:
        lines = (e.stdout or b"").decode().splitlines()
        pytest.fail(f"a reader hung after {lines[-1] if lines else 'the start'}")
    lines = done.stdout.splitlines()
    assert lines[-1] == "done", done.stderr[-3000:]
    bad = [line for line in lines[:-1] if line.split(" ", 1)[1] not in ("ok", "refused", "damaged", "corrupt")]
    assert not bad, bad[:10]
