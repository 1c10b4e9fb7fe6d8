"""Videos of episodes (`simreel.viewers.video`, `simreel video`): files that play, with steps + 1 frames of the size
asked, read back with imageio's ffmpeg; side by side with a replay or a conversion; one-line errors."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.cli.main import main
from simreel.model.lineage import EpisodeProvenance
from simreel.model.state_tree import LeafSpec
from simreel.viewers.video import VideoRun, video_path


def _read(path):
    import imageio.v2 as imageio

    reader = imageio.get_reader(path)
    try:
        return reader.count_frames(), reader.get_meta_data()["size"], reader.get_data(0)
    finally:
        reader.close()


@pytest.fixture
def camera_recording(tmp_path):
    """A recording whose observations hold a 40 x 30 camera: a block that moves one pixel a step; its states finite
    (a NaN or an infinity fails every check, even against itself)."""
    meta = dataclasses.replace(synthetic_meta(), obs_layout={"sensor_data/cam/rgb": LeafSpec((30, 40, 3), "uint8")})
    episodes = []
    for index, T in enumerate((7, 12)):
        ep = synthetic_episode(meta, index, T)
        for leaf in ("actors/cube", "articulations/robot"):  # rotations (a replay checks them), not random numbers
            ep.env_states[leaf][:, 3:7] = (1.0, 0.0, 0.0, 0.0)
        finite = {k: np.nan_to_num(v, posinf=1.0, neginf=-1.0) for k, v in ep.env_states.items()}
        ep = dataclasses.replace(ep, env_states=finite, rewards=np.nan_to_num(ep.rewards, posinf=1.0, neginf=-1.0),
                                 contact_forces=np.nan_to_num(ep.contact_forces, posinf=1.0, neginf=-1.0))
        frames = np.zeros((T + 1, 30, 40, 3), np.uint8)
        for row in range(T + 1):
            frames[row, 10:20, row : row + 8] = 255
        episodes.append(dataclasses.replace(ep, obs={"sensor_data/cam/rgb": frames}))
    return write(tmp_path / "cam.h5", meta, episodes)


def test_a_video_per_episode_has_a_frame_per_state_at_the_size_asked(camera_recording, tmp_path):
    folder = tmp_path / "videos"
    folder.mkdir()
    written = VideoRun(camera_recording, folder, camera="cam", size=(80, 60)).execute()
    assert [(v.index, v.frames) for v in written] == [(0, 8), (1, 13)]
    for v, steps in zip(written, (7, 12), strict=True):
        assert v.path == str(video_path(folder, camera_recording, v.index))
        frames, size, first = _read(v.path)
        assert (frames, size) == (steps + 1, (80, 60)) and first.shape == (60, 80, 3)


def test_recorded_frames_of_a_long_episode_are_read_a_block_at_a_time_in_order(tmp_path):
    """2,500 steps of a 40 x 30 camera span three blocks of rows: every frame is in the video, in order (a bright
    column at x = row % 32 * 2, found again in frames of the first and the last block)."""
    from simreel.formats import open_reader
    from simreel.formats.base import block_rows

    meta = dataclasses.replace(synthetic_meta(), obs_layout={"sensor_data/cam/rgb": LeafSpec((30, 40, 3), "uint8")})
    T = 2500
    frames = np.zeros((T + 1, 30, 40, 3), np.uint8)
    for row in range(T + 1):
        frames[row, :, row % 32 * 2 : row % 32 * 2 + 4] = 255
    path = write(tmp_path / "long.h5", meta, [dataclasses.replace(synthetic_episode(meta, 0, T),
                                                                  obs={"sensor_data/cam/rgb": frames})])
    with open_reader(path) as r:
        assert 2 * block_rows(r.open_episode(0).fields) < T
    [video] = VideoRun(path, tmp_path, camera="cam", size=(40, 30)).execute()
    assert video.frames == T + 1

    import imageio.v2 as imageio

    reader = imageio.get_reader(video.path)
    try:
        assert reader.count_frames() == T + 1
        for row in (5, 2470):
            column = reader.get_data(row)[:, :, 0].mean(axis=0)
            assert abs(int(np.argmax(column)) - (row % 32 * 2 + 1.5)) <= 2, (row, column.round())
    finally:
        reader.close()


def test_side_by_side_with_a_replay_draws_the_verdict(camera_recording, tmp_path):
    folder = tmp_path / "videos"
    folder.mkdir()
    [video] = VideoRun(camera_recording, folder, camera="cam", size=(160, 60), compare=str(camera_recording),
                       episodes=(1,)).execute()
    assert video.verdict == "cam.h5 exact" and video.frames == 13  # itself: no replay of itself
    frames, size, first = _read(video.path)
    assert (frames, size) == (13, (160, 60))
    assert first[20:50, :80].mean() > 5 and first[20:50, 80:].mean() > 5  # both halves show the camera


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--size", "81x60"], "width and height must be even numbers"),
        (["--camera", "wrist"], "holds no rgb observations of camera 'wrist' (cameras: cam)"),
        (["-o", "missing-folder"], "no such folder (create it first); -o names the folder the videos are written in"),
        (["--episodes", "5"], "no episode 5"),
        (["--size", "100000x100000"], "at most 8192 pixels a side"),
    ],
    ids=["odd-size", "unknown-camera", "no-folder", "no-episode", "huge-size"],
)
def test_bad_arguments_are_one_line_exit_2(camera_recording, tmp_path, capsys, args, message):
    args = [str(tmp_path / a) if a == "missing-folder" else a for a in args]
    assert main(["video", str(camera_recording), "-q", "-o", str(tmp_path), "--camera", "cam", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err


def test_an_existing_video_is_not_replaced_without_overwrite(camera_recording, tmp_path, capsys):
    args = ["video", str(camera_recording), "-o", str(tmp_path), "--camera", "cam", "--episodes", "0", "-q"]
    assert main(args) == 0 and "episode 0: " in capsys.readouterr().out
    assert main(args) == 2 and "already exists; pass --overwrite" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0


def test_rendered_from_states_beside_a_conversion(record, lavapipe_env, tmp_path):
    """No camera in the recording: each recorded state is restored and rendered (lavapipe, a child process)."""
    src = record("PickCube-v1", 1, 5)
    done = subprocess.run([sys.executable, "-m", "simreel", "video", str(src), "-o", str(tmp_path), "--size", "96x64",
                           "-q"], env=lavapipe_env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    frames, size, first = _read(video_path(tmp_path, src, 0))
    assert (frames, size) == (6, (96, 64)) and first.std() > 5  # a scene, not a blank frame


def _write_episodes(src, dst, episodes, *, steps=None, provenance=None):
    """Episodes `episodes` of `src` written to `dst` (a replay that holds only some of them), each cut to its
    first `steps` when given; `provenance`: the file's and each episode's, as ``simreel convert`` writes them."""
    from simreel.formats import open_reader, open_writer

    with open_reader(src) as r:
        meta = dataclasses.replace(r.meta, provenance=provenance or {})
        with open_writer(dst, meta) as w:
            for i in episodes:
                ep = r.read_episode(i)
                ep = ep.first_steps(steps) if steps is not None else ep
                if provenance:
                    ep.meta.provenance = EpisodeProvenance(source_episode=i, verdict="within_tolerance")
                w.write_episode(ep)
    return dst


def test_an_episode_the_compare_file_lacks_is_refused_not_paired_with_another(camera_recording, tmp_path, capsys):
    """A replay of episode 1 only: the video of episode 0 is refused (naming the episode it has), never drawn beside
    episode 1's replay and judged by it; the video of episode 1 is made."""
    only_1 = _write_episodes(camera_recording, tmp_path / "only1.h5", [1])
    args = ["video", str(camera_recording), "-q", "-o", str(tmp_path), "--camera", "cam", "--size", "160x60",
            "--compare", str(only_1)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no episode 0 to compare with episode 0 of cam.h5 (it has 1)" in err, err
    assert "--episodes" in err and not list(tmp_path.glob("*.mp4"))
    assert main([*args, "--episodes", "1"]) == 0
    assert "episode 1: " in capsys.readouterr().out and video_path(tmp_path, camera_recording, 1).exists()


def test_a_shorter_replay_is_incomplete_never_exact(camera_recording, tmp_path):
    cut = _write_episodes(camera_recording, tmp_path / "cut.h5", [0, 1], steps=5)
    [video] = VideoRun(camera_recording, tmp_path, camera="cam", size=(160, 60), compare=str(cut),
                       episodes=(1,)).execute()
    assert video.verdict == "cut.h5 incomplete: exact for the first 5 of 12 steps" and video.frames == 13


@pytest.mark.parametrize("own", [True, False], ids=["its-recording", "another-recording"])
def test_a_stored_conversion_verdict_is_used_only_for_the_recording_it_converted(camera_recording, tmp_path, own):
    """A conversion's stored verdict judges the episode it converted; beside another recording (here a copy that
    differs from step 3 on) the two are compared instead."""
    recording = camera_recording
    if not own:
        from simreel.formats import open_reader, open_writer

        with open_reader(camera_recording) as r, open_writer(tmp_path / "moved.h5", r.meta) as w:
            for i in (0, 1):
                ep = r.read_episode(i)
                ep.env_states["actors/cube"][3:, 0] += 1.0
                w.write_episode(ep)
        recording = tmp_path / "moved.h5"
    converted = _write_episodes(camera_recording, tmp_path / "conv.h5", [0, 1],
                                provenance={"operation": "convert", "source": str(camera_recording)})
    [video] = VideoRun(recording, tmp_path, camera="cam", size=(160, 60), compare=str(converted),
                       episodes=(1,)).execute()
    assert video.verdict == ("conversion within tolerance" if own else "conv.h5 diverged")
