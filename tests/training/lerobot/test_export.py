"""`export_lerobot` on real recordings of three tasks, read back with pyarrow against the LeRobot dataset v3.0
layout: every frame's state, action, reward, success and done bit for bit against the source, the index columns,
the episodes table, the tasks, the stats, the metadata's sources and verdicts; and what it refuses."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.training.lerobot.export import export_lerobot

STATE = {"pick": ("obs",), "push": ("obs/state", "env_states/actors/cube"), "stack": ("env_states",)}
"""What each task's export joins into observation.state (pick's and stack's are the defaults)."""


def _source(path: Path) -> list[dict[str, np.ndarray]]:
    with open_reader(path) as reader:
        return [reader.read_episode(m.index).fields() for m in reader.episodes]


def _state_rows(arrays: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """The source's state rows 0..T-1 of the fields `names` choose, flattened and joined in table order."""
    length = len(arrays["actions"])
    keys = [k for n in names for k in arrays if k == n or k.startswith(n + "/")]
    return np.concatenate([arrays[k][:length].reshape(length, -1) for k in keys], axis=1)


@pytest.fixture(scope="module")
def exports(three_tasks, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("lerobot")
    out = {}
    for task, path in three_tasks.items():
        out[task] = folder / task
        state = STATE[task] if task == "push" else ()
        export_lerobot(path, out[task], state=state)
    return out


@pytest.mark.parametrize("task", sorted(STATE))
def test_every_frame_equals_the_source_bit_for_bit(three_tasks, exports, task):
    source = _source(three_tasks[task])
    table = pq.read_table(exports[task] / "data/chunk-000/file-000.parquet")
    frames = {name: table.column(name).combine_chunks() for name in table.column_names}
    state = np.stack(frames["observation.state"].to_numpy(zero_copy_only=False))
    action = np.stack(frames["action"].to_numpy(zero_copy_only=False))
    start = 0
    for number, arrays in enumerate(source):
        length = len(arrays["actions"])
        at = slice(start, start + length)
        assert state[at].tobytes() == _state_rows(arrays, STATE[task]).astype(np.float32).tobytes()
        assert action[at].tobytes() == arrays["actions"].tobytes()
        assert frames["next.reward"].to_numpy()[at].tobytes() == arrays["rewards"].tobytes()
        assert frames["next.success"].to_numpy(zero_copy_only=False)[at].tolist() == arrays["success"].tolist()
        done = (arrays["terminated"] | arrays["truncated"]).tolist()
        assert frames["next.done"].to_numpy(zero_copy_only=False)[at].tolist() == done[:-1] + [True]
        assert frames["frame_index"].to_numpy()[at].tolist() == list(range(length))
        assert frames["episode_index"].to_numpy()[at].tolist() == [number] * length
        assert frames["index"].to_numpy()[at].tolist() == list(range(start, start + length))
        np.testing.assert_array_equal(frames["timestamp"].to_numpy()[at], np.arange(length, dtype=np.float32) / 20)
        start += length
    assert start == table.num_rows


def test_the_layout_and_metadata_are_lerobots_v3(three_tasks, exports):
    root = exports["push"]
    info = json.loads((root / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == 20  # PushCube's control frequency
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert (info["total_episodes"], info["total_frames"], info["total_tasks"]) == (3, 75, 1)
    width = sum(int(np.prod(s.shape)) for s in _state_fields(three_tasks["push"], STATE["push"]))
    assert info["features"]["observation.state"]["shape"] == [width]
    assert info["features"]["action"] == {"dtype": "float32", "shape": [4], "names": [f"action[{k}]" for k in range(4)]}
    assert info["features"]["next.done"] == {"dtype": "bool", "shape": [1], "names": None}
    data = pq.read_table(root / "data/chunk-000/file-000.parquet")
    assert data.column_names == list(info["features"])
    assert [p.relative_to(root).as_posix() for p in sorted(root.rglob("*")) if p.is_file()] == [
        "data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet", "meta/info.json",
        "meta/stats.json", "meta/tasks.parquet"]
    tasks = pq.read_table(root / "meta/tasks.parquet")
    assert tasks.column("task").to_pylist() == ["PushCube-v1"] and tasks.column("task_index").to_pylist() == [0]
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["episode_index"], e["length"], e["dataset_from_index"], e["dataset_to_index"]) for e in episodes] == [
        (0, 25, 0, 25), (1, 25, 25, 50), (2, 25, 50, 75)]
    assert {e["data/file_index"] for e in episodes} == {0} and episodes[0]["tasks"] == ["PushCube-v1"]
    assert [(e["simreel/source_file"], e["simreel/source_episode"]) for e in episodes] == [
        (str(three_tasks["push"]), k) for k in range(3)]
    assert info["simreel"]["sources"][0]["path"] == str(three_tasks["push"])


def _state_fields(path: Path, names: tuple[str, ...]) -> list:
    from simreel.model.fields import episode_fields

    with open_reader(path) as reader:
        fields = episode_fields(reader.meta)
    return [f for n in names for f in fields if f.name == n or f.name.startswith(n + "/")]


def test_the_stats_are_those_of_every_frame(three_tasks, exports):
    stats = json.loads((exports["pick"] / "meta/stats.json").read_text())
    rows = np.concatenate([e["actions"] for e in _source(three_tasks["pick"])]).astype(np.float64)
    assert stats["action"]["count"] == [len(rows)]
    np.testing.assert_allclose(stats["action"]["mean"], rows.mean(axis=0), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(stats["action"]["std"], rows.std(axis=0), rtol=1e-9)
    assert stats["action"]["min"] == rows.min(axis=0).tolist() and stats["action"]["max"] == rows.max(axis=0).tolist()
    assert {"q01", "q10", "q50", "q90", "q99"} <= set(stats["action"]) and set(stats) >= {"observation.state",
                                                                                            "next.reward", "index"}
    episodes = pq.read_table(exports["pick"] / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    first = _source(three_tasks["pick"])[0]["actions"].astype(np.float64)
    np.testing.assert_allclose(episodes[0]["stats/action/q50"], np.quantile(first, 0.5, axis=0))


def test_a_report_keeps_the_verified_episodes_with_their_verdicts(nudged, tmp_path):
    rec, report = nudged
    summary = export_lerobot(rec, tmp_path / "out", report=report)
    assert (summary.episodes, summary.left_out) == (2, 1)
    episodes = pq.read_table(tmp_path / "out/meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [(e["simreel/source_episode"], e["simreel/verdict"]) for e in episodes] == [(0, "exact"), (2, "exact")]
    info = json.loads((tmp_path / "out/meta/info.json").read_text())
    assert info["simreel"]["report"] == str(report) and info["simreel"]["keep"] == ["exact", "within_tolerance"]


def test_nothing_is_replaced_without_overwrite_and_only_a_dataset_with_it(three_tasks, tmp_path):
    out = tmp_path / "out"
    export_lerobot(three_tasks["stack"], out)
    before = (out / "meta/info.json").read_bytes()
    with pytest.raises(UsageError, match=re.escape(f"{out} already exists; pass --overwrite")):
        export_lerobot(three_tasks["stack"], out)
    assert (out / "meta/info.json").read_bytes() == before
    export_lerobot(three_tasks["stack"], out, overwrite=True, task="stack the cubes")
    assert pq.read_table(out / "meta/tasks.parquet").column("task").to_pylist() == ["stack the cubes"]
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(UsageError, match="is a folder that holds no LeRobot dataset; it is kept, even with --overwrite"):
        export_lerobot(three_tasks["stack"], other, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes", "out"]  # no partial folder left


def test_a_failed_export_leaves_no_folder(three_tasks, tmp_path):
    with pytest.raises(UsageError, match="read together need the same features"):
        export_lerobot([three_tasks["pick"], three_tasks["push"]], tmp_path / "out", state=("obs/state",))
    assert list(tmp_path.iterdir()) == []
