"""Reading an episode in blocks of rows (`simreel.formats.base.EpisodeRows`): every reader's blocks put together are
the episode `read_episode` gives, any range of steps reads the rows it names, and the block size follows the bytes
of a row."""

from __future__ import annotations

import numpy as np
import pytest
from support.maniskill_files import record_maniskill

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.formats.base import BLOCK_BYTES, block_rows
from simreel.model.fields import FieldSpec


@pytest.fixture(scope="module")
def recordings(record, tmp_path_factory):
    """The same 2 x 20-step PickCube episodes as simreel HDF5 and MCAP, and a ManiSkill RecordEpisode file."""
    folder = tmp_path_factory.mktemp("blocks")
    h5 = record("PickCube-v1", 2, 20)
    mcap = folder / "rec.mcap"
    assert main(["convert", str(h5), str(mcap), "-q"]) == 0
    maniskill = record_maniskill(folder, "PickCube-v1", episodes=2, steps=20, obs_mode="state")
    return {"h5": h5, "mcap": mcap, "maniskill": maniskill}


@pytest.mark.parametrize("kind", ["h5", "mcap", "maniskill"])
def test_blocks_put_together_are_the_episode(recordings, kind):
    with open_reader(recordings[kind]) as reader:
        for m in reader.episodes:
            whole = reader.read_episode(m.index)
            rows = reader.open_episode(m.index)
            assert rows.meta.length == whole.length == 20
            blocks = list(rows.blocks(7))
            assert [(first, b.rows) for first, b in blocks] == [(0, 7), (7, 7), (14, 6)]
            fields = whole.fields()
            reset = rows.reset()
            for name, a in fields.items():
                per_state = name in reset.arrays
                np.testing.assert_array_equal(np.concatenate([b[name] for _, b in blocks]), a[1:] if per_state else a)
                if per_state:
                    np.testing.assert_array_equal(reset[name], a[:1])
            middle = rows.steps(5, 12)  # across two of the file's messages or chunks
            for name, a in fields.items():
                np.testing.assert_array_equal(middle[name], a[6:13] if name in reset.arrays else a[5:12], err_msg=name)
            without = rows.episode(obs=False)
            assert not without.obs and set(without.env_states) == set(whole.env_states)


def test_a_maniskill_file_keeps_its_quirk_notes_when_read_in_blocks(recordings):
    with open_reader(recordings["maniskill"]) as reader:
        rows = reader.open_episode(0)
        assert rows.meta.initial_state_known  # RecordEpisode's row 0 is the state after reset
        assert rows.meta.notes == reader.read_episode(0).meta.notes


def test_a_block_of_camera_frames_stays_a_few_megabytes():
    rgb = FieldSpec("obs/sensor_data/base_camera/rgb", "uint8", (128, 128, 3), True)
    state = FieldSpec("env_states/actors/cube", "float32", (13,), True)
    assert block_rows([rgb, state]) == BLOCK_BYTES // (128 * 128 * 3 + 52) == 85
    assert block_rows([state]) == 4096  # small rows: long blocks, up to the cap
