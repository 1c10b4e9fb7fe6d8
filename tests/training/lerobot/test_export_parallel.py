"""`simreel export --workers N` and `--ray`: the episodes cut into runs of consecutive episodes, each written by its
own process (or Ray task) into files of its own, and one final step that numbers those files and writes the
metadata. Against the one-worker export of the same recordings (a state-only MCAP of PushCube, an RGB HDF5 of
PickCube rendered on the software Vulkan driver):

- the frames are the same rows, bit for bit (the data files read in order, concatenated);
- stats.json, tasks and info.json are the same bytes (the statistics travel as per-episode moments and are merged
  in the episodes' order: no summation-order tolerance is needed);
- the episodes table is the same but for the files each row points at, and each row points at its own frames;
- the videos decode to the recorded frames within the codec's error (each shard's video starts a new H.264
  stream, so its bytes differ from the one-worker file's);
- Ctrl-C, a worker killed with -9 and a worker's error end the export with one line, leave no folder and no ffmpeg
  process behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from support.children import child_pids, running, simreel, wait_ended
from support.damage import corrupt_chunk
from support.h264_frames import check_within_codec_error, decoded_frames

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.training.lerobot.export import export_lerobot

KEY = "observation.images.base_camera"
FILE_COLUMNS = ("data/chunk_index", "data/file_index")


@pytest.fixture(scope="module")
def rgb_recording(tmp_path_factory) -> Path:
    rec = tmp_path_factory.mktemp("parallel_rgb") / "rgb.h5"
    assert main(["record", "PickCube-v1", "-o", str(rec), "-n", "3", "--max-steps", "20", "--seed", "3",
                 "--obs-mode", "rgb", "--record-obs", "-q"]) == 0
    return rec


@pytest.fixture(scope="module")
def exports(three_tasks, rgb_recording, tmp_path_factory) -> dict[str, dict[int, Path]]:
    """Each recording exported with 1, 2 and (state) 3 workers: 3 workers on 3 episodes, one episode each."""
    folder = tmp_path_factory.mktemp("parallel")
    made: dict[str, dict[int, Path]] = {"state": {}, "rgb": {}}
    for kind, rec, counts in (("state", three_tasks["push"], (1, 2, 3)), ("rgb", rgb_recording, (1, 2))):
        for n in counts:
            made[kind][n] = folder / f"{kind}_{n}"
            export_lerobot(rec, made[kind][n], workers=n)
    return made


def _data(out: Path) -> pa.Table:
    return pa.concat_tables([pq.read_table(p) for p in sorted((out / "data").rglob("*.parquet"))])


def _episodes(out: Path) -> list[dict]:
    return pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()


def _without_files(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if k not in FILE_COLUMNS and not k.startswith("videos/")} for row in rows]


@pytest.mark.parametrize(("kind", "workers"), [("state", 2), ("state", 3), ("rgb", 2)])
def test_more_workers_write_the_same_frames_statistics_and_metadata(exports, kind, workers):
    one, many = exports[kind][1], exports[kind][workers]
    assert _data(many).equals(_data(one))
    for name in ("meta/stats.json", "meta/info.json", "meta/tasks.parquet"):
        assert (many / name).read_bytes() == (one / name).read_bytes(), name
    assert _without_files(_episodes(many)) == _without_files(_episodes(one))
    assert len(list((many / "data").rglob("*.parquet"))) == min(workers, 3)
    assert not [p for p in many.iterdir() if p.name.startswith(".")]  # the shards' own folders are gone


@pytest.mark.parametrize("workers", [2, 3])
def test_each_episode_row_points_at_its_own_frames_in_its_file(exports, workers):
    rows = _episodes(exports["state"][workers])
    files = [r["data/file_index"] for r in rows]
    assert files == sorted(files) and sorted(set(files)) == list(range(workers))  # one file a shard, in order
    for row in rows:
        data = pq.read_table(exports["state"][workers] / f"data/chunk-000/file-{row['data/file_index']:03d}.parquet")
        mine = data.filter(pa.compute.equal(data["episode_index"], row["episode_index"]))
        assert mine["index"].to_pylist() == list(range(row["dataset_from_index"], row["dataset_to_index"]))
        assert mine["frame_index"].to_pylist() == list(range(row["length"]))


def test_each_shards_video_holds_its_episodes_frames_within_the_codecs_error(exports, rgb_recording):
    with open_reader(rgb_recording) as reader:
        recorded = [reader.read_episode(m.index).fields()["obs/sensor_data/base_camera/rgb"][:-1]
                    for m in reader.episodes]
    rows = _episodes(exports["rgb"][2])
    assert [(r[f"videos/{KEY}/file_index"], r[f"videos/{KEY}/from_timestamp"], r[f"videos/{KEY}/to_timestamp"])
            for r in rows] == [(0, 0.0, 1.0), (1, 0.0, 1.0), (1, 1.0, 2.0)]
    shape = recorded[0].shape[1:]
    one = decoded_frames(exports["rgb"][1] / f"videos/{KEY}/chunk-000/file-000.mp4", shape)
    decoded = []
    for row in rows:
        video = decoded_frames(exports["rgb"][2] / f"videos/{KEY}/chunk-000/file-{row[f'videos/{KEY}/file_index']:03d}"
                                                   ".mp4", shape)
        first, last = (round(row[f"videos/{KEY}/{end}_timestamp"] * 20) for end in ("from", "to"))
        decoded.append(video[first:last])
    decoded = np.concatenate(decoded)
    check_within_codec_error(decoded, np.concatenate(recorded))
    check_within_codec_error(decoded, one)  # and near the one-worker video's frames


def test_a_ray_export_writes_the_same_dataset(three_tasks, exports, tmp_path):
    out = tmp_path / "ray"
    start = time.monotonic()
    export_lerobot(three_tasks["push"], out, workers=2, ray="local")
    print(f"ray export: {time.monotonic() - start:.1f} s")
    assert _data(out).equals(_data(exports["state"][1]))
    assert (out / "meta/stats.json").read_bytes() == (exports["state"][1] / "meta/stats.json").read_bytes()
    assert _without_files(_episodes(out)) == _without_files(_episodes(exports["state"][1]))


# ---------------------------------------------------------------------------------------------------- stopping
def _children(pid: int) -> list[int]:
    """The processes `pid` started, none where it has ended meanwhile."""
    try:
        return child_pids(pid)
    except OSError:
        return []


def _descendants(pid: int) -> list[int]:
    found = []
    for child in _children(pid):
        found += [child, *_descendants(child)]
    return found


def _is_ffmpeg(pid: int) -> bool:
    try:
        return "ffmpeg" in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode()
    except OSError:
        return False


def _export_with_a_frozen_worker(rec: Path, out: Path) -> tuple[subprocess.Popen, int, int, list[int]]:
    """`simreel export REC --workers 2` with its worker process held mid-shard: the worker's ffmpeg stopped
    (SIGSTOP), so the worker blocks writing frames to it. The process, the worker, its ffmpeg, every process seen."""
    proc = subprocess.Popen([sys.executable, "-m", "simreel", "export", str(rec), "--to", "lerobot", str(out),
                             "--workers", "2", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: set[int] = set()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        for worker in _children(proc.pid):
            seen.add(worker)
            for ffmpeg in filter(_is_ffmpeg, _children(worker)):
                os.kill(ffmpeg, signal.SIGSTOP)
                return proc, worker, ffmpeg, sorted(seen | set(_descendants(proc.pid)))
        time.sleep(0.005)
    proc.kill()
    raise AssertionError(f"no worker process with an ffmpeg seen: {proc.communicate()}")


def _nothing_left(folder: Path, pids: list[int]) -> None:
    """Every process the export started has ended, and `folder` holds the recording alone."""
    wait_ended(pids, timeout=30)
    assert sorted(p.name for p in folder.iterdir()) == ["rgb.h5", "rgb.json"]


@pytest.fixture
def rgb_copy(rgb_recording, tmp_path) -> Path:
    """The RGB recording, alone in a folder of its own (what is beside it after a stopped export is checked)."""
    rec = tmp_path / "rgb.h5"
    rec.write_bytes(rgb_recording.read_bytes())
    rec.with_suffix(".json").write_bytes(rgb_recording.with_suffix(".json").read_bytes())
    return rec


def test_ctrl_c_stops_the_workers_and_their_ffmpeg_and_publishes_nothing(rgb_copy):
    out = rgb_copy.parent / "ds"
    proc, worker, ffmpeg, pids = _export_with_a_frozen_worker(rgb_copy, out)
    time.sleep(0.5)  # the parent has written its own shard meanwhile, and waits for the worker
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert not running(ffmpeg) and not running(worker)
    _nothing_left(rgb_copy.parent, pids)


def test_a_worker_killed_is_one_line_and_its_ffmpeg_ends_on_its_closed_input(rgb_copy):
    out = rgb_copy.parent / "ds"
    proc, worker, ffmpeg, pids = _export_with_a_frozen_worker(rgb_copy, out)
    os.kill(worker, signal.SIGKILL)
    _, stderr = proc.communicate(timeout=60)
    os.kill(ffmpeg, signal.SIGCONT)  # orphaned, it finds its input closed and ends
    assert proc.returncode == 2, stderr
    assert stderr.startswith("simreel export: error: an export worker process was killed by SIGKILL "), stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    _nothing_left(rgb_copy.parent, pids)


def test_a_workers_error_is_the_exports_one_line(three_tasks, tmp_path):
    rec = tmp_path / "damaged.h5"
    rec.write_bytes(three_tasks["pick"].read_bytes())
    rec.with_suffix(".json").write_bytes(three_tasks["pick"].with_suffix(".json").read_bytes())
    corrupt_chunk(rec, "traj_2/actions", chunk=1, rows=5)  # the last episode: the worker's shard
    done = simreel("export", str(rec), "--to", "lerobot", str(tmp_path / "ds"), "--workers", "2", "-q")
    assert done.returncode == 2, done.stderr  # in a process of its own: the workers' stderr is its stderr too
    assert done.stderr.startswith(f"simreel export: error: {rec}: traj_2/actions is corrupt"), done.stderr
    assert len(done.stderr.splitlines()) == 1, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.h5", "damaged.json"]


def test_workers_below_one_are_refused(three_tasks, tmp_path, capsys):
    assert main(["export", str(three_tasks["push"]), "--to", "lerobot", str(tmp_path / "ds"), "--workers", "0"]) == 2
    assert capsys.readouterr().err == "simreel export: error: --workers must be >= 1, got 0\n"
    assert json.dumps(sorted(p.name for p in tmp_path.iterdir())) == "[]"


REPO = Path(__file__).resolve().parents[3]
LEROBOT_PYTHON = Path(os.environ.get("SIMREEL_LEROBOT_PYTHON", REPO / ".cache/lerobot-venv/bin/python"))


@pytest.mark.skipif(not LEROBOT_PYTHON.is_file(), reason="no LeRobot venv: run `make lerobot-env`")
@pytest.mark.parametrize(("kind", "workers", "script"), [("state", 3, "lerobot_read.py"),
                                                         ("rgb", 2, "lerobot_read_videos.py")])
def test_lerobot_reads_the_shards_files_as_the_one_workers_file(exports, tmp_path, kind, workers, script):
    """LeRobot's own loader: every frame, window and pad mask the same; the video frames within the codec's
    error of the one-worker video's."""
    read = {}
    for n in (1, workers):
        subprocess.run([str(LEROBOT_PYTHON), "-W", "ignore", str(REPO / "tests/support" / script),
                        str(exports[kind][n]), str(tmp_path / f"{n}.npz")], check=True, timeout=300,
                       capture_output=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
        with np.load(tmp_path / f"{n}.npz") as data:
            read[n] = dict(data)
    assert read[1].keys() == read[workers].keys()
    for key, values in read[1].items():
        if key == KEY:
            check_within_codec_error(read[workers][key], values)
        else:
            assert np.array_equal(read[workers][key], values), key
