"""Run by LeRobot's own venv (`make lerobot-env`): read every frame's camera images of a LeRobot dataset folder with
lerobot's `LeRobotDataset` and save them, uint8 (frames, H, W, 3) by video key, to an .npz.

    python lerobot_read_videos.py DATASET OUT.npz

LeRobotDataset finds each frame in its episode's video file (the episodes table's ``videos/<key>/from_timestamp``
plus the frame's timestamp) and asks its decoder for that time. Its two decoders do not run in that venv:
torchcodec has no build for the CPU torch 2.13 there, and its PyAV path calls `torchvision.io.VideoReader`, which
torchvision 0.28 no longer has. So the PyAV path's decoder is given here with the same contract, on PyAV directly:
the frames closest to the asked timestamps, each within `tolerance_s` of one (else an error, as LeRobot's), as
float32 (n, 3, H, W) in [0, 1]. Everything else (which file, which time) is LeRobot's.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import av  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from lerobot.datasets import video_utils  # noqa: E402
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

_DECODED: dict[str, tuple[np.ndarray, np.ndarray]] = {}


def _decode_with_pyav(video_path, timestamps, tolerance_s, backend="pyav", log_loaded_timestamps=False):
    path = str(video_path)
    if path not in _DECODED:
        with av.open(path) as container:
            frames = [(f.time, f.to_ndarray(format="rgb24")) for f in container.decode(video=0)]
        _DECODED[path] = (np.array([t for t, _ in frames]), np.stack([a for _, a in frames]))
    times, images = _DECODED[path]
    picked = [int(np.argmin(np.abs(times - t))) for t in timestamps]
    off = [abs(times[k] - t) for k, t in zip(picked, timestamps, strict=True)]
    if max(off) >= tolerance_s:
        raise AssertionError(f"{path}: no frame within {tolerance_s} s of {timestamps} (off by {max(off)})")
    return torch.from_numpy(images[picked]).permute(0, 3, 1, 2).float() / 255


def main(root: str, out: str) -> None:
    video_utils.decode_video_frames_torchvision = _decode_with_pyav
    dataset = LeRobotDataset("simreel/export", root=root, video_backend="pyav")
    frames = [dataset[k] for k in range(len(dataset))]
    arrays = {key: np.stack([(f[key].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8) for f in frames])
              for key in dataset.meta.video_keys}
    arrays["episode_index"] = np.stack([f["episode_index"].numpy() for f in frames])
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
