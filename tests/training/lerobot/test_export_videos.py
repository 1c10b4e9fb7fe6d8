"""Camera frames exported as LeRobot v3.0 videos: a PickCube recording made with RGB observations (rendered on the
software Vulkan driver) exports one H.264 mp4 for its camera, episodes one after another, with info.json's video
feature and the episodes table's timestamps as LeRobot writes them; the frames decoded (by ffmpeg here, by LeRobot's
own `LeRobotDataset` in its venv) are the recorded ones, frame for frame, within the codec's error.

The codec's error, measured on these frames (x264, crf 18, yuv420p): mean absolute error 3.6-3.9 of 255 per frame,
single pixels up to ~130 at coloured edges (the chroma is stored at half resolution). Each decoded frame is nearer
its own recorded frame than any other of the recording, so no frame is shifted or repeated."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from support.h264_frames import check_within_codec_error, decoded_frames

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.training.lerobot.export import export_lerobot

REPO = Path(__file__).resolve().parents[3]
LEROBOT_PYTHON = Path(os.environ.get("SIMREEL_LEROBOT_PYTHON", REPO / ".cache/lerobot-venv/bin/python"))
KEY = "observation.images.base_camera"


@pytest.fixture(scope="module")
def camera_export(tmp_path_factory) -> tuple[Path, Path, np.ndarray]:
    """A PickCube recording with RGB observations (2 episodes of 8 steps), its export, and the frames the video
    should hold: each episode's per-state rows 0 .. T-1 of its camera."""
    folder = tmp_path_factory.mktemp("videos")
    rec, out = folder / "rgb.h5", folder / "ds"
    assert main(["record", "PickCube-v1", "-o", str(rec), "-n", "2", "--max-steps", "8", "--seed", "1",
                 "--obs-mode", "rgb", "--record-obs", "-q"]) == 0
    export_lerobot(rec, out)
    with open_reader(rec) as reader:
        frames = np.concatenate([reader.read_episode(m.index).fields()["obs/sensor_data/base_camera/rgb"][:-1]
                                 for m in reader.episodes])
    return rec, out, frames


def test_the_camera_becomes_one_video_of_every_episode_as_lerobot_lays_it_out(camera_export):
    _, out, frames = camera_export
    info = json.loads((out / "meta/info.json").read_text())
    assert info["video_path"] == "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    assert info["features"][KEY] == {
        "dtype": "video", "shape": [128, 128, 3], "names": ["height", "width", "channels"],
        "info": {"video.height": 128, "video.width": 128, "video.codec": "h264", "video.pix_fmt": "yuv420p",
                 "video.is_depth_map": False, "video.fps": 20, "video.channels": 3, "has_audio": False}}
    # the images are in the video, not in the state (obs/sensor_data/base_camera/rgb is 49152 values)
    assert info["features"]["observation.state"]["shape"][0] < 100
    assert not any("rgb" in name for name in info["features"]["observation.state"]["names"])
    episodes = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e[f"videos/{KEY}/chunk_index"], e[f"videos/{KEY}/file_index"], e[f"videos/{KEY}/from_timestamp"],
             e[f"videos/{KEY}/to_timestamp"]) for e in episodes] == [(0, 0, 0.0, 0.4), (0, 0, 0.4, 0.8)]
    stats = json.loads((out / "meta/stats.json").read_text())[KEY]
    assert np.asarray(stats["mean"]).shape == (3, 1, 1) and 0 <= np.min(stats["min"]) <= np.max(stats["max"]) <= 1
    np.testing.assert_allclose(np.asarray(stats["mean"]).ravel(), (frames[:, ::4, ::4] / 255).mean(axis=(0, 1, 2)))

    decoded = decoded_frames(out / f"videos/{KEY}/chunk-000/file-000.mp4", frames.shape[1:])
    check_within_codec_error(decoded, frames)


@pytest.mark.skipif(not LEROBOT_PYTHON.is_file(), reason="no LeRobot venv: run `make lerobot-env`")
def test_lerobots_loader_decodes_every_frame_of_every_episode(camera_export, tmp_path):
    _, out, frames = camera_export
    subprocess.run([str(LEROBOT_PYTHON), "-W", "ignore", str(REPO / "tests/support/lerobot_read_videos.py"), str(out),
                    str(tmp_path / "frames.npz")], check=True, timeout=300, capture_output=True,
                   env={**os.environ, "HF_HUB_OFFLINE": "1"})
    with np.load(tmp_path / "frames.npz") as got:
        assert got["episode_index"].tolist() == [0] * 8 + [1] * 8
        check_within_codec_error(got[KEY], frames)
