"""Body poses through a control-mode conversion (`simreel.replay.convert.convert`): a recording with body poses converts
to one with the converted run's own poses of the same bodies, not silently none."""

from __future__ import annotations

import numpy as np

from simreel.formats import open_reader
from simreel.replay.convert.convert import convert_recording


def test_a_control_mode_conversion_writes_its_own_runs_body_poses(record, tmp_path):
    """Regression: `convert --control-mode` dropped the recorded body_poses without a word."""
    src, out = record("PickCube-v1", 1, 6, "--poses"), tmp_path / "jp.h5"
    report = convert_recording(src, out, control_mode="pd_joint_pos")
    assert report.ok and report.written == [0]
    with open_reader(src) as original, open_reader(out) as converted:
        assert original.meta.pose_bodies and converted.meta.pose_bodies == original.meta.pose_bodies
        recorded, ran = original.read_episode(0).body_poses, converted.read_episode(0).body_poses
        assert ran is not None and ran.shape == recorded.shape
        np.testing.assert_allclose(ran[:, :, :3], recorded[:, :, :3], atol=1e-3)  # the run tracked the recorded one
