"""A session logged in small blocks of rows (read from the file, compared and sent a block at a time) holds the same
content, read back with Rerun's own reader, as one logged in a single block: the block size changes how much is in
memory, never what is shown."""

from __future__ import annotations

import pytest
from support.viewer_data import STEPS  # the length of the `pickcube_h5` recording

from simreel.viewers import build_session

DIVERGE_AT = 12


def _content(rrd) -> dict[str, dict[str, list[str]]]:
    """Every entity's columns as (step, value) rows in step order (chunking differs with the block size); repr keeps
    NaN equal to NaN."""
    return {entity: {column: sorted(repr(row) for row in rows) for column, rows in columns.items()}
            for entity, columns in rrd.data.items()}


@pytest.fixture
def saved(view_env, rrd_reader, tmp_path):
    """`saved(source, name, **options)`: the session of `source` saved to ``<name>.rrd``, and its content."""

    def save(source, name, **options):
        out = tmp_path / f"{name}.rrd"
        with build_session(source, env=view_env, geometry="collision", **options) as session:
            session.save(out)
        return session, _content(rrd_reader(out))

    return save


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_small_blocks_log_what_one_block_logs(suffix, pickcube_h5, variant, saved, tmp_path):
    source = variant(pickcube_h5, tmp_path / f"camera{suffix}", camera=True)  # no body poses: restored from states
    _, whole = saved(source, "whole", block_steps=STEPS + 1)
    _, blocks = saved(source, "blocks", block_steps=7)
    assert "/cameras/base_camera/rgb" in whole and "/cameras/base_camera/depth" in whole
    assert len(whole["/cameras/base_camera/rgb"]["Image:buffer"]) == STEPS + 1  # a frame per state row
    assert set(blocks) == set(whole)
    for entity in whole:
        assert blocks[entity] == whole[entity], entity


def test_compare_in_small_blocks_matches_one_block(pickcube_h5, variant, saved, tmp_path):
    recording = variant(pickcube_h5, tmp_path / "camera.mcap", camera=True)
    replayed = variant(pickcube_h5, tmp_path / "replayed.h5", shift_from=DIVERGE_AT, camera=True)
    one, whole = saved(recording, "whole", compare=replayed, block_steps=STEPS + 1)
    small, blocks = saved(recording, "blocks", compare=replayed, block_steps=7)
    assert small.divergence == one.divergence and small.divergence.step == DIVERGE_AT - 1
    assert small.comparison.comparison.max_abs_error == one.comparison.comparison.max_abs_error
    assert "obs/sensor_data/base_camera/rgb" in small.comparison.comparison.errors  # frames compared, block by block
    assert any(e.startswith("/plots/error/") for e in whole) and "/compared/cube" in whole
    assert set(blocks) == set(whole)
    for entity in whole:
        assert blocks[entity] == whole[entity], entity
