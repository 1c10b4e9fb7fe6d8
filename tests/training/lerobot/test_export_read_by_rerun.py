"""`simreel export --to lerobot` read back with Rerun's own LeRobot reader (`rerun.experimental.LeRobotReader`,
rerun-sdk 0.41, in simreel's venv): it takes each export as a LeRobot v3 dataset with the source's episodes, and the
actions, states and rewards it loads equal the source's, frame by frame, as Rerun holds them (float64 scalars: each
float32 value exactly). Rerun 0.41 does not load boolean features (next.success, next.done: it says so in a warning),
so those are checked by pyarrow and LeRobot's loader (test_export.py, test_export_read_by_lerobot.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simreel.formats import open_reader
from simreel.training.lerobot.export import export_lerobot

LeRobotReader = pytest.importorskip("rerun.experimental").LeRobotReader


@pytest.fixture(scope="module")
def exports(three_tasks, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("lerobot_rerun")
    for task, path in three_tasks.items():
        export_lerobot(path, folder / task)
    return {task: folder / task for task in three_tasks}


def _series(reader, episode: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each scalar feature Rerun loads of `episode`: (its frame indices, its values per frame)."""
    out = {}
    for chunk in reader.stream(episode).to_chunks():
        batch = chunk.to_record_batch()
        if "Scalars:scalars" in batch.schema.names:
            frames = batch.column("frame_index").to_numpy()
            values = np.array(batch.column("Scalars:scalars").to_pylist(), dtype=np.float64)
            out[chunk.entity_path.lstrip("/")] = (frames, values)
    return out


@pytest.mark.parametrize("task", ["pick", "push", "stack"])
def test_rerun_reads_every_frame_the_export_holds_as_the_source_has_it(three_tasks, exports, task):
    reader = LeRobotReader(exports[task])
    with open_reader(three_tasks[task]) as source:
        episodes = [source.read_episode(m.index) for m in source.episodes]
    assert reader.version == "v3" and reader.episodes() == list(range(len(episodes)))
    for number, episode in enumerate(episodes):
        series = _series(reader, number)
        length = episode.length
        for name, want in (("action", episode.actions), ("next.reward", episode.rewards)):
            frames, values = series[name]
            assert frames.tolist() == list(range(length))
            assert values.reshape(length, -1).tobytes() == want.astype(np.float32).astype(np.float64).reshape(
                length, -1).tobytes()
        frames, state = series["observation.state"]
        assert frames.tolist() == list(range(length)) and state.shape[0] == length
        assert state.tobytes() == _default_state(episode.fields(), length).astype(np.float64).tobytes()


def _default_state(rows: dict[str, np.ndarray], length: int) -> np.ndarray:
    """What an export joins into observation.state by default, as float32: the recorded observations, else the
    state dict, flattened in table order, rows 0..T-1."""
    group = "obs" if any(k.startswith("obs/") for k in rows) else "env_states"
    return np.concatenate([rows[k][:length].reshape(length, -1) for k in rows if k.startswith(group + "/")],
                          axis=1).astype(np.float32)
