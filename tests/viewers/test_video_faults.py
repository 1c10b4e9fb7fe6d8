"""`simreel video` under bad input and faults: a frame rate that is no rate, a compared recording of another env,
damaged episodes, a full disk, two runs writing into one folder: one line and exit 2, intact videos kept, no
temporary file left, nothing replaced without --overwrite."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.damage import corrupt_chunk
from support.mcap_samples import synthetic_episode, synthetic_meta, write
from support.small_disk import fill, small_disk

from simreel.cli.main import main
from simreel.model.state_tree import LeafSpec
from simreel.viewers.video import VideoRun, video_path


def _camera_recording(path: Path, lengths: tuple[int, ...] = (7, 12), *, side: int = 32, noise: bool = False,
                      env_id: str = "Synthetic-v0") -> Path:
    """A recording whose observations hold a `side` x `side` camera (`noise`: random pixels, which H.264 cannot
    compress: a big video)."""
    meta = dataclasses.replace(synthetic_meta(), env_id=env_id,
                               obs_layout={"sensor_data/cam/rgb": LeafSpec((side, side, 3), "uint8")})
    rng = np.random.default_rng(0)
    episodes = []
    for index, T in enumerate(lengths):
        frames = (rng.integers(0, 256, (T + 1, side, side, 3), dtype=np.uint8) if noise
                  else np.full((T + 1, side, side, 3), 40 * index, np.uint8))
        episodes.append(dataclasses.replace(synthetic_episode(meta, index, T), obs={"sensor_data/cam/rgb": frames}))
    return write(path, meta, episodes)


def _frames(path: Path) -> int:
    import imageio.v2 as imageio

    reader = imageio.get_reader(path)
    try:
        return reader.count_frames()
    finally:
        reader.close()


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.mark.parametrize("fps", ["0", "-5", "nan", "inf", "1e+308", "1e+10", "1e-05"])
def test_a_frame_rate_that_is_not_a_positive_number_is_one_line_exit_2(tmp_path, capsys, fps):
    """Before, -5 and nan failed inside ffmpeg (exit 3) and 0 silently meant the default; 1e+308, 1e+10 and 1e-05
    too (ffmpeg refuses such rates: "Error opening input files: Invalid argument", exit 3)."""
    recording = _camera_recording(tmp_path / "cam.h5")
    assert main(["video", str(recording), "-o", str(tmp_path), "--camera", "cam", "--fps", fps, "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--fps {fps}: frames per second must be a positive number" in err, err
    assert not list(tmp_path.glob("*.mp4"))


def test_a_compared_recording_of_another_env_is_refused_as_view_refuses_it(tmp_path, capsys):
    """Its states would be restored into this recording's env and drawn as its replay: the same check and message
    as `view --compare` (`simreel.viewers.sources.check_comparable`)."""
    recording = _camera_recording(tmp_path / "cam.h5")
    other = _camera_recording(tmp_path / "other.h5", env_id="OtherTask-v1")
    assert main(["video", str(recording), "-o", str(tmp_path), "--camera", "cam", "--compare", str(other),
                 "--size", "64x32", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "--compare other.h5 episode 0: it is a recording of OtherTask-v1, not of Synthetic-v0" in err
    assert not list(tmp_path.glob("*.mp4"))


def test_a_damaged_episode_gets_no_video_and_is_named_with_exit_2(tmp_path, capsys):
    """Episode 1's data fails its checksum: the videos of 0 and 2 are written, and the run ends with one line naming
    episode 1 and how to recover the file, exit 2 (before: exit 0, episode 1 left out without a word)."""
    recording = _camera_recording(tmp_path / "cam.h5", (4, 6, 5))
    corrupt_chunk(recording, "traj_1/actions", chunk=1, rows=2)
    folder = tmp_path / "videos"
    folder.mkdir()
    assert main(["video", str(recording), "-o", str(folder), "--camera", "cam", "-q"]) == 2
    captured = capsys.readouterr()
    [line] = captured.err.splitlines()
    assert "damaged, no video of: episode 1 (traj_1/actions is corrupt" in line
    assert f"the other videos were written; `simreel recover {recording}` keeps its intact episodes" in line
    assert sorted(p.name for p in folder.iterdir()) == ["cam_ep0.mp4", "cam_ep2.mp4"]
    assert [_frames(folder / "cam_ep0.mp4"), _frames(folder / "cam_ep2.mp4")] == [5, 6]
    assert "episode 0: " in captured.out and "episode 2: " in captured.out


def test_an_episode_the_file_lists_as_damaged_is_named(tmp_path, capsys):
    """Episode 0's metadata is damaged (the reader lists it in `damaged`, not among the episodes): all episodes
    asked for, the others' videos are written and it is named, exit 2; asked for by index, it is said to be
    damaged, not missing."""
    import h5py

    recording = _camera_recording(tmp_path / "cam.h5", (4, 6))
    with h5py.File(recording, "r+") as f:
        for name in list(f["traj_0"].attrs):
            del f["traj_0"].attrs[name]
    folder = tmp_path / "videos"
    folder.mkdir()
    assert main(["video", str(recording), "-o", str(folder), "--camera", "cam", "-q"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert "damaged, no video of: traj_0: " in line and "`simreel recover" in line
    assert sorted(p.name for p in folder.iterdir()) == ["cam_ep1.mp4"]
    assert main(["video", str(recording), "-o", str(folder), "--camera", "cam", "--episodes", "0", "-q"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert "no readable episode 0 (readable: 1); damaged: traj_0: " in line and "`simreel recover" in line


def test_a_full_disk_is_one_line_exit_2_and_leaves_no_temporary_file(tmp_path):
    """A 40 KiB disk and a video of noise that does not fit: before, exit 3 with "OSError: Broken pipe" and
    ffmpeg's dump."""
    recording = _camera_recording(tmp_path / "noise.h5", (40,), side=96, noise=True)
    with small_disk(tmp_path, 40) as disk:
        fill(disk, leave_kib=16)
        done = subprocess.run([sys.executable, "-m", "simreel", "video", str(recording), "-o", str(disk),
                               "--camera", "cam", "--size", "96x96", "-q"], capture_output=True, text=True,
                              timeout=300)
        left = sorted(p.name for p in disk.iterdir() if not p.name.startswith("filler"))
    assert done.returncode == 2, done.stderr[-2000:]
    [line] = done.stderr.splitlines()
    assert line == (f"simreel video: error: {video_path(disk, recording, 0)}: the disk is full: the video was not "
                    "written; free some space or write to another disk")
    assert left == []


def test_two_runs_into_one_folder_neither_clobbers_the_other(tmp_path):
    """While one run encodes a video, another writes the same video whole (here: inside the first's progress
    callback, so the two overlap at a known point). Each has a temporary file of its own (before, both used
    `.NAME.partial.mp4`: the second's rename took the first's file away, which then died with exit 3), and the
    first, without --overwrite, does not replace the video that appeared meanwhile: it stops with one line."""
    from simreel.errors import UsageError

    recording = _camera_recording(tmp_path / "cam.h5", (30,))
    folder = tmp_path / "videos"
    folder.mkdir()
    first = VideoRun(recording, folder, camera="cam", size=(32, 32))
    second = VideoRun(recording, folder, camera="cam", size=(32, 32), fps=5)
    seen: list[list[str]] = []

    def progress(frames: int) -> None:
        if not seen:
            seen.append(_leftovers(folder))  # the first's temporary file, being written
            [written] = second.execute()
            assert written.frames == 31
            seen.append(_leftovers(folder))

    with pytest.raises(UsageError, match="a file appeared there while this one was written"):
        first.execute(progress)
    out = video_path(folder, recording, 0)
    assert len(seen[0]) == 1 and seen[1] == seen[0]  # the second's own temporary file is gone, the first's kept
    assert _leftovers(folder) == []  # and the first's is removed when it stops

    import imageio.v2 as imageio

    reader = imageio.get_reader(out)
    try:
        assert reader.get_meta_data()["fps"] == 5  # the second run's video, kept
    finally:
        reader.close()
    assert _frames(out) == 31



def test_a_maniskill_file_without_states_is_rendered_from_its_stepped_actions(lavapipe_env, tmp_path):
    """A RecordEpisode file recorded with record_env_state=False: before, "give --camera NAME for recorded images"
    though it holds none; now its actions are stepped from the reproduced reset, as `view` does
    (`simreel.viewers.session.states_by_stepping`), and each state reached is rendered."""
    from support.maniskill_files import record_maniskill

    demos = record_maniskill(tmp_path, "PickCube-v1", episodes=1, steps=8, record_env_state=False)
    done = subprocess.run([sys.executable, "-m", "simreel", "video", str(demos), "-o", str(tmp_path), "--size",
                           "64x64", "-q"], env=lavapipe_env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    import imageio.v2 as imageio

    reader = imageio.get_reader(video_path(tmp_path, demos, 0))
    try:
        frames = [reader.get_data(i) for i in range(reader.count_frames())]
    finally:
        reader.close()
    assert len(frames) == 9 and frames[0].std() > 5  # a scene per state, not a blank frame
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5  # the robot moved


def test_ctrl_c_names_the_videos_written_before_it(tmp_path):
    """Ctrl-C between two episodes' videos: each video already written is listed on stdout, as after a full run
    (before, only "interrupted": which of the folder's videos were whole was left to guess), exit 130."""
    import os
    import signal
    import time

    recording = _camera_recording(tmp_path / "many.h5", (120,) * 12, side=96, noise=True)
    out = tmp_path / "videos"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "simreel", "video", str(recording), "-o", str(out), "--camera",
                             "cam", "--size", "96x96", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not any(p.suffix == ".mp4" and not p.name.startswith(".") for p in out.iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert stderr.splitlines()[-1] == "simreel video: interrupted"
    listed = {line.split(": ")[1].split(" (")[0] for line in stdout.splitlines()}
    videos = {str(p) for p in out.iterdir() if p.suffix == ".mp4" and not p.name.startswith(".")}
    assert listed == videos and 1 <= len(videos) < 12
    assert all(_frames(Path(v)) == 121 for v in videos)


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_ctrl_c_python_swallowed_during_a_video_stops_the_next_one(tmp_path, monkeypatch, capsys):
    """A Ctrl-C that lands in a finalizer (the garbage collector's, during an encode) is swallowed by Python: the run
    went on to write every video and exited 0 (seen once in CI). The next video now does not start: exit 130."""
    import gc
    import signal
    import weakref

    recording = _camera_recording(tmp_path / "three.h5", (5, 5, 5))
    write_one = VideoRun._episode

    def then_a_swallowed_ctrl_c(self, frames, index, progress):
        video = write_one(self, frames, index, progress)
        thing = type("Thing", (), {})()
        weakref.finalize(thing, signal.raise_signal, signal.SIGINT)  # raised in the finalizer, which Python swallows
        del thing
        gc.collect()
        return video

    monkeypatch.setattr(VideoRun, "_episode", then_a_swallowed_ctrl_c)
    out = tmp_path / "videos"
    out.mkdir()
    assert main(["video", str(recording), "-o", str(out), "--camera", "cam", "-q"]) == 130
    std = capsys.readouterr()
    assert std.err.splitlines()[-1] == "simreel video: interrupted"
    assert [line.split(" (")[0] for line in std.out.splitlines()] == [f"episode 0: {video_path(out, recording, 0)}"]
    assert sorted(p.name for p in out.iterdir()) == [video_path(out, recording, 0).name]


def test_a_video_never_writes_over_a_recording_it_reads(tmp_path, capsys):
    """A link in the folder named as a video leads to the recording (or to --compare's): with --overwrite the video
    was written through it, replacing the recording (exit 0). Now one line, exit 2, before any video; both files
    unchanged."""
    recording = _camera_recording(tmp_path / "cam.h5")
    compare = _camera_recording(tmp_path / "other.h5")
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "cam_ep0.mp4").symlink_to(recording)
    (videos / "cam_ep1.mp4").symlink_to(compare)
    before = {p: p.read_bytes() for p in (recording, compare)}
    args = ["video", str(recording), "-o", str(videos), "--camera", "cam", "--overwrite", "-q"]
    assert main([*args, "--episodes", "0"]) == 2
    assert capsys.readouterr().err == (f"simreel video: error: the video {videos}/cam_ep0.mp4 is the recording "
                                       f"{recording}; write it to another file\n")
    assert main([*args, "--episodes", "1", "--compare", str(compare)]) == 2
    assert f"the video {videos}/cam_ep1.mp4 is the recording {compare}; " in capsys.readouterr().err
    assert {p: p.read_bytes() for p in (recording, compare)} == before
    assert _leftovers(videos) == []


def test_an_episode_named_twice_gets_one_video(tmp_path, capsys):
    """`--episodes 0,0` (or 0-1,1) encoded the video twice and then refused the second copy as "a file appeared
    there while this one was written (another run?)", exit 2."""
    recording = _camera_recording(tmp_path / "cam.h5")
    assert main(["video", str(recording), "-o", str(tmp_path), "--camera", "cam", "--episodes", "0-1,1,0", "-q"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines() == [f"episode 0: {tmp_path}/cam_ep0.mp4 (8 frames)",
                                f"episode 1: {tmp_path}/cam_ep1.mp4 (13 frames)"]


@pytest.mark.parametrize(
    ("output", "message"),
    [
        ("", "an empty path names no folder (an unset shell variable?); name the folder for the videos (-o . for "
             "the working folder)"),
        ("{tmp}/out.mp4", "-o {tmp}/out.mp4: no such folder (create it first); -o names the folder the videos are "
                          "written in, as <name>_ep<N>.mp4"),
        ("{tmp}/cam.h5", "-o {tmp}/cam.h5: not a folder; -o names the folder the videos are written in"),
    ],
    ids=["empty", "a-video-name", "a-file"],
)
def test_an_output_that_names_no_folder_says_what_o_is(tmp_path, monkeypatch, capsys, output, message):
    """`-o "$UNSET"` wrote the videos into the working folder, and `-o out.mp4` said "not a folder (create it
    first)": a folder named out.mp4."""
    recording = _camera_recording(tmp_path / "cam.h5")
    monkeypatch.chdir(tmp_path)
    output = output.format(tmp=tmp_path)
    assert main(["video", str(recording), "-o", output, "--camera", "cam", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.format(tmp=tmp_path) in err, err
    assert not list(tmp_path.rglob("*.mp4"))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"overwrite": "no"}, "overwrite='no': give True or False"),
        ({"episodes": 1}, "episodes=1: not a list of indices; give episode indices"),
        ({"episodes": "1-0"}, "episodes='1-0': range '1-0' runs backwards; give episode indices"),
        ({"size": 256}, "size=256: give (width, height), two even ints such as (256, 256)"),
        ({"size": (64.0, 64.0)}, "size=(64.0, 64.0): give (width, height)"),
        ({"fps": "30"}, "--fps '30': frames per second must be a positive number from 0.001 to 1000"),
        ({"camera": 3}, "camera=3: give the name of a camera"),
        ({"compare": 3}, "3: give a recording's path, a str or Path"),
        ({"options": {"fps": 3}}, "options={'fps': 3}: give a VideoOptions, or its fields as keywords"),
        ({"bogus": 1}, "bogus=1: give only the options VideoOptions has: "),  # was: TypeError naming its __init__
    ],
    ids=["overwrite-str", "episodes-int", "episodes-bad-text", "size-int", "size-float", "fps-str", "camera-int",
         "compare-int", "options-dict", "unknown"],
)
def test_python_options_of_the_wrong_type_are_a_usage_error_and_nothing_is_replaced(tmp_path, options, message):
    """Before: overwrite="no" replaced the existing video; episodes="0-1" was "no episode 0 (episodes: 0, 1)";
    the others TypeErrors or ValueErrors from inside, or (sizes of floats) passed the check."""
    from simreel.errors import UsageError

    recording = _camera_recording(tmp_path / "cam.h5")
    video = video_path(tmp_path, recording, 0)
    video.write_bytes(b"an earlier video")
    with pytest.raises(UsageError) as caught:
        VideoRun(recording, tmp_path, **{"camera": "cam", **options}).execute()
    assert str(caught.value).startswith(message), caught.value
    assert video.read_bytes() == b"an earlier video"


def test_a_recording_or_folder_of_the_wrong_type_is_a_usage_error(tmp_path):
    """Before: TypeError from pathlib ("expected str, bytes or os.PathLike object, not NoneType")."""
    from simreel.errors import UsageError

    recording = _camera_recording(tmp_path / "cam.h5")
    with pytest.raises(UsageError, match=r"^None: give a recording's path, a str or Path$"):
        VideoRun(None, tmp_path)
    with pytest.raises(UsageError, match=r"^folder=None: give the folder for the videos, a str or Path$"):
        VideoRun(recording, None)


def test_python_episodes_as_text_are_parsed_as_on_the_command_line(tmp_path):
    """episodes="0-1" named episodes "0", "-" and "1" and failed with "no episode 0 (episodes: 0, 1)"."""
    recording = _camera_recording(tmp_path / "cam.h5")
    assert VideoRun(recording, tmp_path, camera="cam", episodes="0-1").indices == [0, 1]


def test_no_render_device_says_to_take_the_frames_from_a_recorded_camera(tmp_path):
    """Before: the env's own error ended "...or use obs_mode='state' and no render_mode", an option `video` does not
    take; now the run stops before any work and names the recording's cameras (`--camera`) and the Vulkan setting
    that gives no device."""
    import os

    recording = _camera_recording(tmp_path / "cam.h5")
    env = {**os.environ, "VK_ICD_FILENAMES": str(tmp_path / "no_icd.json")}
    done = subprocess.run([sys.executable, "-m", "simreel", "video", str(recording), "-o", str(tmp_path), "-q"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr[-2000:]
    [line] = done.stderr.splitlines()
    assert line.startswith(f"simreel video: error: {recording}: rendering the recorded states needs a render device")
    assert f"fix or unset VK_ICD_FILENAMES={tmp_path / 'no_icd.json'}" in line
    assert line.endswith("; or take the frames from a recorded camera with --camera NAME (cam)")
    assert not list(tmp_path.glob("*.mp4"))


def test_overwrite_replaces_a_link_named_as_a_video_and_not_the_file_it_leads_to(tmp_path, capsys):
    """A video path that is a link to a recording this command does not read: `--overwrite` replaces the link by
    the video, as every writer replaces one; the recording it led to stays as it was (it once became the mp4)."""
    recording = _camera_recording(tmp_path / "cam.h5")
    other = _camera_recording(tmp_path / "other.h5", (3,))
    before = other.read_bytes()
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "cam_ep0.mp4").symlink_to(other)
    assert main(["video", str(recording), "-o", str(videos), "--camera", "cam", "--episodes", "0", "--overwrite",
                 "-q"]) == 0
    assert not (videos / "cam_ep0.mp4").is_symlink() and other.read_bytes() == before
    assert _leftovers(videos) == []
