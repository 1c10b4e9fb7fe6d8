"""The scene fingerprint of a control-mode conversion's output (`simreel.replay.convert.convert`): its controllers are the
new control mode's, so its replay finds the scene it was converted in."""

from __future__ import annotations

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.replay.convert.convert import convert_recording


def test_a_converted_recording_replays_without_a_scene_difference(record, tmp_path, capsys):
    """Regression: the output kept the input's controller settings, so each episode of its replay said "scene
    differs from the recording: controller panda/arm: use_delta True → False" beside `exact`."""
    src, out = record("PickCube-v1", 1, 6), tmp_path / "jp.h5"
    assert convert_recording(src, out, control_mode="pd_joint_pos").ok
    with open_reader(src) as original, open_reader(out) as converted:
        before, after = original.meta.scene_fingerprint, converted.meta.scene_fingerprint
        assert after["bodies"] == before["bodies"] and after["controllers"] != before["controllers"]
    capsys.readouterr()
    assert main(["replay", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "1 exact" in printed and "scene differs" not in printed
