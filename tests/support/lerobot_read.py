"""Run by LeRobot's own venv (`make lerobot-env`): read a LeRobot dataset folder with lerobot's `LeRobotDataset`,
once frame by frame and once with windows (`delta_timestamps`: two states back, three actions ahead), and save
every frame's values and pad masks to an .npz for the test to compare with the source recording.

    python lerobot_read.py DATASET OUT.npz
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np  # noqa: E402
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402


def main(root: str, out: str) -> None:
    plain = LeRobotDataset("simreel/export", root=root)
    dt = 1 / plain.fps
    windows = LeRobotDataset("simreel/export", root=root,
                             delta_timestamps={"observation.state": [-dt, 0.0], "action": [0.0, dt, 2 * dt]})
    keys = ["observation.state", "action", "next.reward", "next.success", "next.done", "frame_index",
            "episode_index", "index", "task_index", "timestamp"]
    frames = [plain[k] for k in range(len(plain))]
    arrays = {key: np.stack([f[key].numpy() for f in frames]) for key in keys if key in frames[0]}
    window = [windows[k] for k in range(len(windows))]
    for key in ("observation.state", "action", "observation.state_is_pad", "action_is_pad"):
        arrays[f"window/{key}"] = np.stack([w[key].numpy() for w in window])
    arrays["tasks"] = np.array([f["task"] for f in frames])
    arrays["num_episodes"] = np.array(plain.num_episodes)
    arrays["fps"] = np.array(plain.fps)
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
