"""Exports read back by LeRobot's own `LeRobotDataset` (lerobot 0.4.4, in the venv `make lerobot-env` makes; skipped
without it): every frame's state, action, reward, success and done equal the source bit for bit, and its
`delta_timestamps` windows and `_is_pad` masks fall where the episodes begin and end."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from simreel.formats import open_reader
from simreel.training.lerobot.export import export_lerobot

REPO = Path(__file__).resolve().parents[3]
LEROBOT_PYTHON = Path(os.environ.get("SIMREEL_LEROBOT_PYTHON", REPO / ".cache/lerobot-venv/bin/python"))
pytestmark = pytest.mark.skipif(not LEROBOT_PYTHON.is_file(), reason="no LeRobot venv: run `make lerobot-env`")


def _read_with_lerobot(root: Path, out: Path) -> dict[str, np.ndarray]:
    subprocess.run([str(LEROBOT_PYTHON), "-W", "ignore", str(REPO / "tests/support/lerobot_read.py"), str(root),
                    str(out)], check=True, timeout=300, capture_output=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    with np.load(out) as data:
        return dict(data)


@pytest.mark.parametrize(("task", "state"), [("pick", ("obs",)), ("push", ("obs/state", "env_states/actors/cube")),
                                             ("stack", ("env_states",))])
def test_lerobots_loader_reads_every_frame_as_recorded(three_tasks, tmp_path, task, state):
    export_lerobot(three_tasks[task], tmp_path / "ds", state=state)
    got = _read_with_lerobot(tmp_path / "ds", tmp_path / "frames.npz")
    with open_reader(three_tasks[task]) as reader:
        episodes = [reader.read_episode(m.index).fields() for m in reader.episodes]
        env_id = reader.meta.env_id
    assert int(got["num_episodes"]) == len(episodes) and int(got["fps"]) == 20
    start = 0
    for number, arrays in enumerate(episodes):
        length = len(arrays["actions"])
        at = slice(start, start + length)
        keys = [k for n in state for k in arrays if k == n or k.startswith(n + "/")]
        want_state = np.concatenate([arrays[k][:length].reshape(length, -1) for k in keys], axis=1)
        assert got["observation.state"][at].tobytes() == want_state.astype(np.float32).tobytes()
        assert got["action"][at].tobytes() == arrays["actions"].tobytes()
        assert got["next.reward"][at].tobytes() == arrays["rewards"].tobytes()
        assert got["next.success"][at].tolist() == arrays["success"].tolist()
        assert got["next.done"][at].tolist() == [bool(d) for d in (arrays["terminated"] | arrays["truncated"])[:-1]] + [True]
        assert got["episode_index"][at].tolist() == [number] * length
        # windows: the state before (padded at the first frame), the action and the two after (padded at the end)
        assert got["window/observation.state_is_pad"][at].tolist() == [[True, False]] + [[False, False]] * (length - 1)
        assert got["window/action_is_pad"][at][-2:].tolist() == [[False, False, True], [False, True, True]]
        assert not got["window/action_is_pad"][at][:-2].any()
        assert got["window/action"][at][:-2, 1].tobytes() == arrays["actions"][1:-1].tobytes()
        start += length
    assert start == len(got["action"]) and set(got["tasks"].tolist()) == {env_id}
