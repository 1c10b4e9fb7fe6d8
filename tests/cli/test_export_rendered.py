"""`simreel export IN --to lerobot OUT --obs-mode rgb`: camera frames a state-only recording lacks, re-rendered from
its states (on lavapipe here) and exported. The one-step export equals the two-step route (`simreel convert
--obs-mode rgb`, then a plain export) row for row and bit for bit; its video decodes to the frames that conversion
rendered, within the codec's error; its actions are the source's, bit for bit; its metadata names the source (not
the scratch recording) and the conversion; a replay report chooses the source's episodes; bad input is one line,
exit 2, before anything is converted.

Cost on the shared 2-core machine (2026-12-02): the module's default tests ~40-55 s (the shared fixture ~21 s: a
replay, an export and a conversion of 10-step PickCube episodes at 64x64, each building an env with a camera); the
`slow` ones, PushCube ~14-19 s and Ctrl-C in a child process 1-19 s, more."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from support.h264_frames import check_within_codec_error, decoded_frames
from support.nudged import nudged_copy

from simreel.cli.main import main
from simreel.formats import open_reader, open_writer
from simreel.training.lerobot.export import export_lerobot

KEY = "observation.images.base_camera"
CAMERA = "obs/sensor_data/base_camera/rgb"
RENDER = ["--obs-mode", "rgb", "--camera-size", "64x64", "-q"]


@pytest.fixture(scope="module")
def rendered(record, tmp_path_factory) -> dict[str, Path]:
    """A state-only PickCube recording (3 episodes of 10 steps, episode 1 nudged so that its replay diverges), its
    replay report, its export with --report and --obs-mode rgb (episodes 0 and 2), and the two-step route's
    conversion and plain export of the same episodes."""
    folder = tmp_path_factory.mktemp("rendered")
    rec = nudged_copy(record("PickCube-v1", 3, 10), folder / "pick.h5")
    report = folder / "report.json"
    assert main(["replay", str(rec), "--report", str(report), "-q"]) == 1
    out = folder / "ds"
    assert main(["export", str(rec), "--to", "lerobot", str(out), "--report", str(report), *RENDER]) == 0
    converted = folder / "converted.h5"
    assert main(["convert", str(rec), str(converted), "--episodes", "0,2", *RENDER]) == 0
    export_lerobot(converted, folder / "two_steps")
    return {"rec": rec, "report": report, "out": out, "converted": converted, "two_steps": folder / "two_steps"}


def _info(out: Path) -> dict:
    return json.loads((out / "meta/info.json").read_text())


def _episodes(out: Path) -> list[dict]:
    return pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pylist()


def _status(args: list[str]) -> int:
    try:
        return main(args)
    except SystemExit as exit_:
        return int(exit_.code)


def test_the_frames_are_the_rendered_ones_and_the_rows_those_of_the_two_step_route(rendered):
    out, two_steps = rendered["out"], rendered["two_steps"]
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    assert data.equals(pq.read_table(two_steps / "data/chunk-000/file-000.parquet"))
    assert _info(out)["features"] == _info(two_steps)["features"]
    assert _info(out)["features"][KEY]["shape"] == [64, 64, 3]
    with open_reader(rendered["rec"]) as source:
        actions = np.concatenate([source.read_episode(i).actions for i in (0, 2)])
    assert np.array_equal(np.stack(data.column("action").to_numpy(zero_copy_only=False)), actions)
    with open_reader(rendered["converted"]) as conv:
        frames = np.concatenate([conv.read_episode(i).fields()[CAMERA][:-1] for i in (0, 2)])
    assert frames.shape == (20, 64, 64, 3) and frames.std() > 10  # a real picture, not a blank one
    check_within_codec_error(decoded_frames(out / f"videos/{KEY}/chunk-000/file-000.mp4", (64, 64, 3)), frames)


def test_the_metadata_names_the_source_its_verdicts_and_the_conversion(rendered, capsys):
    rec, out = rendered["rec"], rendered["out"]
    simreel = _info(out)["simreel"]
    (source,) = simreel["sources"]
    with open_reader(rec) as r:
        recording_id = r.meta.recording_id
    assert (source["path"], source["recording_id"], source["obs_mode"], source["episodes"]) == (
        str(rec), recording_id, "state", [0, 2])
    assert source["rendered"]["conversion"]["obs_mode"] == ["state", "rgb"]
    assert source["rendered"]["conversion"]["sensor_configs"] == {"width": 64, "height": 64}
    assert source["rendered"]["left_out"] == {} and "states and actions equal" in source["rendered"]["written_check"]
    assert simreel["report"] == str(rendered["report"]) and simreel["keep"] == ["exact", "within_tolerance"]
    assert [(e["simreel/source_file"], e["simreel/source_episode"], e["simreel/verdict"]) for e in _episodes(out)] == [
        (str(rec), 0, "exact"), (str(rec), 2, "exact")]
    assert not list(out.parent.glob(".ds*"))  # no scratch recording or staged folder left


@pytest.mark.parametrize(("extra", "message"), [
    (["--obs-mode", "colour"], "PickCube-v1: no obs mode 'colour'; the obs modes there are state, "),
    (["--camera-size", "64x64"], "--camera-size and --shader apply to re-rendered observations: add --obs-mode"),
    (["--obs-mode", "rgb", "--camera-size", "64"], "argument --camera-size"),
])
def test_bad_render_options_are_one_line_and_exit_2(rendered, tmp_path, capsys, extra, message):
    assert _status(["export", str(rendered["rec"]), "--to", "lerobot", str(tmp_path / "ds"), "-q", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("simreel export: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert not list(tmp_path.iterdir())


def test_an_existing_out_is_refused_before_anything_is_converted(rendered, capsys):
    out = rendered["out"]
    before = (out / "meta/info.json").read_bytes()
    start = time.monotonic()
    assert _status(["export", str(rendered["rec"]), "--to", "lerobot", str(out), *RENDER]) == 2
    assert time.monotonic() - start < 3  # no env was built
    assert capsys.readouterr().err == (f"simreel export: error: {out} already exists; pass --overwrite to replace it "
                                       "(overwrite=True from Python)\n")
    assert (out / "meta/info.json").read_bytes() == before
    assert not list(out.parent.glob(".ds*"))


def test_an_export_that_fails_after_the_conversion_leaves_nothing(rendered, tmp_path, capsys):
    """--state names a field the converted episodes lack: found only once they exist, after the conversion; the
    scratch recordings and the staged dataset are removed (as on Ctrl-C: the same context managers)."""
    out = tmp_path / "ds"
    assert _status(["export", str(rendered["rec"]), "--to", "lerobot", str(out), "--state", "obs/nope", "--report",
                    str(rendered["report"]), *RENDER]) == 2
    err = capsys.readouterr().err
    assert err.startswith("simreel export: error: ") and err.count("\n") == 1 and f"{rendered['rec']} (re-rendered): episode 0 has no obs/nope" in err, err
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_ctrl_c_during_the_conversion_leaves_nothing(rendered, tmp_path):
    """SIGINT once the conversion writes into the scratch folder (beside its lock): exit 130, no scratch or staged
    folder left."""
    out = tmp_path / "ds"
    child = subprocess.Popen([sys.executable, "-m", "simreel", "export", str(rendered["rec"]), "--to", "lerobot",
                              str(out), *RENDER], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    scratch = tmp_path / ".ds.replay.partial"
    while child.poll() is None and time.monotonic() < deadline and len(list(scratch.glob("*"))) < 2:
        time.sleep(0.05)
    assert child.poll() is None, child.communicate()
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err
    assert not list(tmp_path.iterdir())


def test_a_recording_with_those_observations_is_refused(record, tmp_path, capsys):
    rec = record("PickCube-v1", 1, 5, "--record-obs")
    assert _status(["export", str(rec), "--to", "lerobot", str(tmp_path / "ds"), "--obs-mode", "state", "-q"]) == 2
    assert capsys.readouterr().err == (f"simreel export: error: {rec} holds state observations already (recorded "
                                       "with them): export it without --obs-mode, or give --camera-size/--shader to "
                                       "render them anew\n")


def _altered(source: Path, rec: Path, episodes: tuple[int, ...]) -> Path:
    """A copy of `source` whose `episodes` have their recorded reward at step 3 altered: the reward recomputed from
    the restored state disagrees, so their conversion check fails."""
    with open_reader(source) as r, open_writer(rec, r.meta) as w:
        for m in r.episodes:
            episode = r.read_episode(m.index)
            episode.rewards[3] += 1.0 * (m.index in episodes)
            w.write_episode(episode)
    return rec


def test_an_episode_that_fails_its_conversion_check_is_left_out_and_named(record, tmp_path, capsys):
    rec = _altered(record("PickCube-v1", 2, 5), tmp_path / "altered.h5", (1,))
    out = tmp_path / "ds"
    capsys.readouterr()
    assert main(["export", str(rec), "--to", "lerobot", str(out), *RENDER]) == 1
    printed = capsys.readouterr().out
    assert printed.startswith("exported 1 episode(s), 5 frames at 20 fps from 1 recording(s)")
    assert f"1 left out by the conversion check: {rec} episode 1 (not verified (diverged))" in printed, printed
    assert [e["simreel/source_episode"] for e in _episodes(out)] == [0]
    assert list(_info(out)["simreel"]["sources"][0]["rendered"]["left_out"]) == ["1"]


def test_no_episode_passing_its_check_exports_nothing(record, tmp_path, capsys):
    rec = _altered(record("PickCube-v1", 2, 5), tmp_path / "altered.h5", (0, 1))
    capsys.readouterr()
    assert main(["export", str(rec), "--to", "lerobot", str(tmp_path / "ds"), *RENDER]) == 1
    assert capsys.readouterr().out == (f"nothing exported: no episode passed its conversion check ({rec} episode 0 "
                                       f"(not verified (diverged)), {rec} episode 1 (not verified (diverged)))\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["altered.h5", "altered.json"]


@pytest.mark.slow
def test_a_second_task_renders_and_exports(record, tmp_path):
    rec = record("PushCube-v1", 2, 6)
    out = tmp_path / "push"
    assert main(["export", str(rec), "--to", "lerobot", str(out), *RENDER]) == 0
    converted = tmp_path / "push.h5"
    assert main(["convert", str(rec), str(converted), *RENDER]) == 0
    with open_reader(converted) as conv:
        frames = np.concatenate([conv.read_episode(m.index).fields()[CAMERA][:-1] for m in conv.episodes])
        actions = np.concatenate([conv.read_episode(m.index).actions for m in conv.episodes])
    check_within_codec_error(decoded_frames(out / f"videos/{KEY}/chunk-000/file-000.mp4", (64, 64, 3)), frames)
    data = pq.read_table(out / "data/chunk-000/file-000.parquet")
    assert np.array_equal(np.stack(data.column("action").to_numpy(zero_copy_only=False)), actions)
    assert [e["simreel/verdict"] for e in _episodes(out)] == [None, None]
