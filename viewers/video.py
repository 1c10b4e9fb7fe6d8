"""An mp4 per episode of any recording, optionally side by side with its replay or conversion, the step and the
verdict drawn in: what `simreel video` runs.

Frames: one per state row (row 0 after the reset, row t+1 after step t), so a video has steps + 1 frames. They
come from a camera the recording holds as observations (``camera="base_camera"``: its ``rgb``), else from
ManiSkill's render camera (``render_mode="rgb_array"``) after restoring each recorded state into the rebuilt env
(a render device is needed: a GPU or lavapipe); a ManiSkill file recorded without states has its actions stepped
from the reset first, as ``simreel view`` does. With ``compare``, the other recording's episode of the same index
is drawn on the right, and the verdict is that of its conversion (`EpisodeMeta.provenance`, written by
``simreel convert``, used only when that file converted this very recording and episode) or, for a replay (or any
other file), of comparing the two (`simreel.verdicts.compare`, ``simreel replay``'s rules; a shorter replay is incomplete),
said of what the other file is (`simreel.viewers.sources.EpisodeRun.subject`: ``replay diverged``, ``second.h5
diverged``).
Encoding: H.264 (yuv420p) by ffmpeg (imageio's binary), through a temporary file renamed when the video is whole.
"""

from __future__ import annotations

import dataclasses
import numbers
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simreel.errors import RecordingFileError, StorageError, UsageError
from simreel.formats import open_reader, recording_files
from simreel.io.durable import raise_if_stopped
from simreel.io.paths import refuse_empty
from simreel.io.targets import check_distinct, check_output, staged_output
from simreel.model.components import DEFAULT_TOLERANCES, Tolerances
from simreel.model.episode import Episode
from simreel.model.lineage import EpisodeProvenance
from simreel.model.meta import RecordingMeta
from simreel.model.selection import EpisodeSelection
from simreel.options.checks import check_flag, options_with, whole_number_pair
from simreel.sim.user_code import import_specs, refuse_untrusted_imports
from simreel.viewers.compare import ViewComparison, compare_for_view, compared_role, judging_tolerances
from simreel.viewers.session import states_by_stepping
from simreel.viewers.sources import read_compare, read_run

__all__ = ["VideoOptions", "VideoRun", "EpisodeVideo", "video_path", "MAX_SIDE", "FPS_RANGE"]

MAX_SIDE = 8192
"""The largest width or height of a video (``--size``), 8K: larger frames cost gigabytes of memory to render and
encode (100000 x 100000 is 30 GB a frame), and get a process killed rather than a video."""
FPS_RANGE = (0.001, 1000.0)
"""The frame rates a video may have (``--fps``): ffmpeg refuses rates far outside (1e-05 and 1e10 frames a second
fail in it), and a video player has no use for them."""


@dataclass(frozen=True)
class VideoOptions:
    """What `VideoRun` writes.

    Attributes:
        episodes: episode indices, an `EpisodeSelection` (``--episodes 0,3-7``) or indices (None: all).
        compare: another recording of the same task (a replay, a conversion, a second recording) shown on the right.
        size: (width, height) of the video frame (both even: H.264 in yuv420p); side by side, each half is one
            recording.
        camera: a camera whose ``rgb`` observations the recording holds (None: render each restored state).
        fps: frames per second, a positive number (None: the recording's control frequency, else 20).
        mode: whose default tolerances judge a replay shown with `compare` (as ``simreel view --compare``; None: a
            replay or a conversion of this recording is judged with the tolerances that judged it when it was
            written, any other file with actions', `simreel.viewers.compare.judging_tolerances`).
        overwrite: replace existing videos.
        imports: ``--import`` specs registering the task, used instead of the recorded ones (else those are found
            where `simreel.sim.user_code.resolve_task_imports` looks, beside the recording too).
        trust_recorded_imports: import the code the recording names (``--trust-recorded-imports``); without it, or
            `imports`, only modules installed in this Python are (`simreel.sim.user_code.refuse_untrusted_imports`).
    """

    episodes: EpisodeSelection | Sequence[int] | None = None
    compare: str | None = None
    size: tuple[int, int] = (512, 256)
    camera: str | None = None
    fps: float | None = None
    mode: str | None = None
    overwrite: bool = False
    imports: tuple[str, ...] = ()
    trust_recorded_imports: bool = False

    def __post_init__(self) -> None:
        # ranges, whatever the numbers, as replay and convert keep them; text such as "0,3-7" is parsed
        object.__setattr__(self, "episodes", EpisodeSelection.of(self.episodes))
        object.__setattr__(self, "imports", import_specs(self.imports))

    def check(self) -> None:
        """`UsageError` for options no recording could make work: a size, rate, mode or flag of the wrong kind."""
        check_flag("overwrite", self.overwrite)
        check_flag("trust_recorded_imports", self.trust_recorded_imports)
        whole_number_pair("size", self.size, "(width, height), two even ints such as (256, 256)")
        if self.camera is not None and not isinstance(self.camera, str):
            raise UsageError(f"camera={self.camera!r}: give the name of a camera whose rgb images the recording holds")
        width, height = self.size
        if width < 2 or height < 2 or width % 2 or height % 2:
            raise UsageError(f"--size {width}x{height}: width and height must be even numbers >= 2 (H.264, yuv420p)")
        if max(width, height) > MAX_SIDE:
            raise UsageError(f"--size {width}x{height}: at most {MAX_SIDE} pixels a side (a frame that size already "
                             "takes 200 MB of memory); choose a smaller size")
        if self.compare is not None and width % 4:
            raise UsageError(f"--size {width}x{height}: side by side, the width must be a multiple of 4")
        if self.mode is not None and self.mode not in DEFAULT_TOLERANCES:
            raise UsageError(f"--mode {self.mode!r}: expected one of {', '.join(DEFAULT_TOLERANCES)}")
        low, high = FPS_RANGE
        if self.fps is not None and not (isinstance(self.fps, numbers.Real) and low <= self.fps <= high):
            shown = f"{self.fps:g}" if isinstance(self.fps, numbers.Real) else repr(self.fps)
            raise UsageError(f"--fps {shown}: frames per second must be a positive number from {low:g} to {high:g}; "
                             "leave it out for the recording's control frequency")


@dataclass
class EpisodeVideo:
    """One written video."""

    index: int
    path: str
    frames: int
    verdict: str = ""


def video_path(folder: str | Path, recording: str | Path, index: int) -> Path:
    """Where the video of episode `index` of `recording` goes: ``<folder>/<recording stem>_ep<index>.mp4``."""
    return Path(folder) / f"{Path(recording).stem}_ep{index}.mp4"


class VideoRun:
    """Videos of a recording's episodes: checked when built (options, targets, files), written by `execute`.

    Damaged episodes get no video, and are never left out silently: those the file lists as damaged, and those
    whose data fails to read, are named in `damaged` (`damage_error`), the others' videos written.
    """

    def __init__(self, path: str | Path, folder: str | Path, options: VideoOptions | None = None, **overrides: Any):
        opts = options_with(VideoOptions, options, overrides, "VideoRun(path, folder, fps=10)")
        opts.check()
        if not isinstance(folder, (str, os.PathLike)):
            raise UsageError(f"folder={folder!r}: give the folder for the videos, a str or Path")
        refuse_empty(folder, what="folder", instead="name the folder for the videos (-o . for the working folder)")
        self.path, self.folder, self.options = str(path), Path(folder), opts
        if not self.folder.is_dir():
            what = "not a folder" if self.folder.exists() else "no such folder (create it first)"
            raise UsageError(f"-o {folder}: {what}; -o names the folder the videos are written in, as "
                             "<name>_ep<N>.mp4")
        with open_reader(path) as r:
            self.meta = r.meta
            self.indices = r.named_episodes(opts.episodes) if opts.episodes is not None else [m.index for m in r.episodes]
            self.lengths = {i: r.episode_meta(i).length for i in self.indices}
            self.damaged: list[str] = list(r.damaged) if opts.episodes is None else []
            """What is wrong with each episode that got no video because it is damaged."""
            self._recover_hint = r.recover_hint()
        self.compared: dict[int, int] = {}
        """Episode index → the index of the episode of `options.compare` drawn beside it."""
        self.compared_as = ""
        """What the verdicts call `options.compare` (`EpisodeRun.subject`): ``replay``, ``conversion``, its file name."""
        if opts.compare is not None:
            self.compared, self.compared_as = _compared_indices(path, opts.compare, self.indices)
        self.written: list[EpisodeVideo] = []
        """The videos `execute` has written so far."""
        self.notes: list[str] = []
        """What the videos' verdicts were judged with, where that is not plain (`judging_tolerances`)."""
        have = sorted({k.split("/")[1] for k in self.meta.obs_layout if k.startswith("sensor_data/")})
        if opts.camera is not None and not any(k.startswith(f"sensor_data/{opts.camera}/rgb") for k in self.meta.obs_layout):
            raise UsageError(f"{path} holds no rgb observations of camera {opts.camera!r} (cameras: "
                             f"{', '.join(have) or 'none'}); leave --camera out to render the recorded states")
        self._check_targets()
        if opts.camera is None:
            refuse_untrusted_imports(self.meta.imports, explicit=opts.imports, trust=opts.trust_recorded_imports,
                                     source=self.path)
            _check_render_device(path, have)

    def _check_targets(self) -> None:
        """`UsageError` unless every video can be written: none is a recording read (`check_distinct`: a recording
        is known by its bytes, whatever its name, so a link named like a video can lead to one), and `check_output`
        lets each be written (an existing one only with `overwrite`)."""
        videos = [video_path(self.folder, self.path, i) for i in self.indices]
        for recording in [self.path] + ([self.options.compare] if self.options.compare is not None else []):
            check_distinct({"the video": videos}, recording_files(recording), input_label=f"the recording {recording}")
        for video in videos:
            check_output(video, overwrite=self.options.overwrite)

    @property
    def frames(self) -> int:
        """Frames this run writes (steps + 1 per episode)."""
        return sum(n + 1 for n in self.lengths.values())

    def execute(self, progress: Callable[[int], None] | None = None) -> list[EpisodeVideo]:
        """Write every video but those of damaged episodes (added to `damaged`); `progress(frames)` after each
        frame written. Each video written is in `written` as soon as it is, also when a stop or an error ends the
        run before the others."""
        frames = _FrameSource(self.meta, self.options, self.path)
        written = self.written
        try:
            for i in self.indices:
                raise_if_stopped()  # a Ctrl-C swallowed during the last video (in a finalizer) stops the next one
                try:
                    written.append(self._episode(frames, i, progress))
                except StorageError:
                    raise
                except RecordingFileError as e:  # its data (or that of the episode beside it) fails to read
                    ours = Path(e.path).resolve() == Path(self.path).resolve()
                    self.damaged.append(f"episode {i} ({e.problem if ours else e})")
        finally:
            frames.close()
        return written

    def damage_error(self) -> RecordingFileError | None:
        """The error that names the damaged episodes that got no video (None: there are none)."""
        if not self.damaged:
            return None
        return RecordingFileError(self.path, f"damaged, no video of: {'; '.join(self.damaged)}; the other videos "
                                             f"were written; {self._recover_hint}")

    def _episode(self, frames: _FrameSource, index: int, progress: Callable[[int], None] | None) -> EpisodeVideo:
        """One video. The episodes are read without their observations; recorded camera frames are read a block
        at a time as they are encoded."""
        with open_reader(self.path) as r:
            left = r.open_episode(index).episode(obs=False)
        right, labels = None, _Labels(left.length, success=left.success)
        if self.options.compare is not None:
            right, labels = self._compared(left, index)
        out = video_path(self.folder, self.path, index)
        count = _encode(out, self._frames(frames, left, right, labels, progress), self._fps(),
                        overwrite=self.options.overwrite)
        return EpisodeVideo(index, str(out), count, labels.verdict)

    def _compared(self, left: Episode, index: int) -> tuple[Episode, _Labels]:
        """The episode of `options.compare` drawn beside episode `index` (`left`), and the labels that say its
        verdict: the one its conversion stored (`_stored_conversion`), else that of comparing the two."""
        with open_reader(self.options.compare) as other:
            right = other.open_episode(self.compared[index]).episode(obs=False)
            conversion = _stored_conversion(other.meta, right, self.meta, self.path, index)
            asked = None if self.options.mode is None else Tolerances.for_mode(self.options.mode)
            tolerances, note = judging_tolerances(asked, other.meta, self.meta, self.path)
        if note and note not in self.notes:
            self.notes.append(note)
        if conversion is not None:
            return right, _conversion_labels(left, conversion)
        cmp = compare_for_view(left, right, channels=self.meta.contact_channels, tolerances=tolerances)
        return right, _compared_labels(left, cmp, self.compared_as)

    def _frames(self, frames: _FrameSource, left: Episode, right: Episode | None, labels: _Labels,
                progress: Callable[[int], None] | None) -> Iterator[np.ndarray]:
        width, height = self.options.size
        half = (width // 2, height) if right is not None else (width, height)
        lefts = frames.of(self.path, left, half)
        rights = frames.of(self.options.compare, right, half) if right is not None else None
        last_right = None
        for row, image in enumerate(lefts):
            if rights is not None:
                last_right = next(rights, last_right)
                image = np.concatenate([image, last_right], axis=1)
            yield _draw(image, labels.text(row))
            if progress is not None:
                progress(1)

    def _fps(self) -> float:
        return float(self.options.fps if self.options.fps is not None else self.meta.control_freq or 20.0)


def _compared_indices(path: str | Path, compare: str, indices: list[int]) -> tuple[dict[int, int], str]:
    """For each episode of `indices`, the episode of `compare` drawn beside it, chosen and checked as ``view
    --compare`` does (`simreel.viewers.sources.read_compare`: the same index, of the same env, with states in
    common): another env's states restored into this one's would draw nonsense. An episode `compare` lacks is
    refused (naming the episodes it has), never shown beside another episode's replay or silently alone. Also
    what `compare` is called (`EpisodeRun.subject`)."""
    found, subject = {}, ""
    with open_reader(path) as r, open_reader(compare) as other:
        for i in indices:
            recorded = read_run(r, i)
            run = read_compare(other, recorded, option="--episodes")
            found[i], subject = run.episode.meta.index, run.subject
    return found, subject


# ------------------------------------------------------------------------------------------------ frames
class _FrameSource:
    """RGB frames of an episode's state rows: recorded camera observations, or renders of restored states."""

    def __init__(self, meta: RecordingMeta, options: VideoOptions, path: str) -> None:
        self.meta, self.options, self.path = meta, options, path
        self.env: Any = None
        self.size: tuple[int, int] | None = None
        self.scene_seed: Any = None

    def of(self, path: str | Path, episode: Episode, size: tuple[int, int]) -> Iterator[np.ndarray]:
        """The frames of `episode` (read from the recording `path`) at `size`."""
        if self.options.camera is not None:
            return (_resize(a, size) for a in _recorded_frames(path, episode.meta.index, self.options.camera))
        return self._rendered(episode, size)

    def _rendered(self, episode: Episode, size: tuple[int, int]) -> Iterator[np.ndarray]:
        from simreel.sim.rebuild import reset_to_episode
        from simreel.sim.state import restore_state, state_row

        env = self._env(size)
        done = reset_to_episode(env, episode.meta, scene_seed=self.scene_seed)
        self.scene_seed = done.scene_seed
        if not episode.env_states:  # a ManiSkill file recorded without states: step its actions, as `view` does
            states_by_stepping(env.unwrapped, episode)
        for row in range(episode.length + 1):
            restore_state(env.unwrapped, state_row(episode.env_states, row), elapsed_steps=row)
            yield _to_image(env.render(), size)

    def _env(self, size: tuple[int, int]) -> Any:
        from simreel.sim.rebuild import GYM_MAKE_SEED, env_from_meta, state_only_kwargs
        from simreel.sim.user_code import resolve_task_imports

        if self.env is not None and self.size == size:
            return self.env
        self.close()
        kwargs = state_only_kwargs(self.meta)
        kwargs.update(render_mode="rgb_array", human_render_camera_configs={"width": size[0], "height": size[1]})
        found = resolve_task_imports(self.meta.imports, explicit=self.options.imports, recording=self.path,
                                     trust=self.options.trust_recorded_imports)
        self.env = env_from_meta(dataclasses.replace(self.meta, imports=found), num_envs=1, sim_backend="physx_cpu",
                                 obs_mode="none", render_backend="auto", env_kwargs=kwargs)
        self.size, self.scene_seed = size, GYM_MAKE_SEED
        return self.env

    def close(self) -> None:
        if self.env is not None:
            self.env.close()
            self.env = None


def _check_render_device(path: str | Path, cameras: list[str]) -> None:
    """`RenderUnavailableError` before any work where the recorded states are to be rendered and nothing here
    renders, saying how to get a device or, where the recording holds camera images, to take the frames from them
    (`--camera`): the env's own error would suggest an observation mode, which `video` does not take."""
    from simreel.errors import RenderUnavailableError
    from simreel.sim.make import render_fix
    from simreel.sim.render_device import probe_render_device

    probe = probe_render_device()
    if probe.backend != "none":
        return
    instead = (f"; or take the frames from a recorded camera with --camera NAME ({', '.join(cameras)})" if cameras
               else " (the recording holds no camera images, which --camera NAME would take instead)")
    raise RenderUnavailableError(f"{path}: rendering the recorded states needs a render device, and there is none "
                                 f"({probe.detail}); to render, {render_fix('auto')}{instead}")


def _recorded_frames(path: str | Path, index: int, camera: str) -> Iterator[np.ndarray]:
    """The `camera`'s rgb observation of every state row of episode `index` of `path`, read a block at a time."""
    key = f"obs/sensor_data/{camera}/rgb"
    with open_reader(path) as r:
        rows = r.open_episode(index)
        reset = rows.reset()
        if key not in reset.arrays:
            raise UsageError(f"{path} holds no rgb observations of camera {camera!r}")
        yield from reset[key]
        for _, block in rows.blocks():
            yield from block[key]


def _to_image(rendered: Any, size: tuple[int, int]) -> np.ndarray:
    image = rendered.cpu().numpy() if hasattr(rendered, "cpu") else np.asarray(rendered)
    return _resize(image.reshape(image.shape[-3:]), size)


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`image` (H, W, 3) uint8 at `size` (width, height)."""
    image = np.asarray(image)[..., :3].astype(np.uint8, copy=False)
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    from PIL import Image

    return np.asarray(Image.fromarray(image).resize(size, Image.BILINEAR))


# ------------------------------------------------------------------------------------------------ labels
@dataclass
class _Labels:
    """What each frame says: the step, and (side by side) the verdict with the step it changes at."""

    steps: int
    verdict: str = ""
    out_at: int | None = None
    """State row from which the right-hand run is out of tolerance."""
    detail: str = ""
    success: np.ndarray | None = None
    checked_rows: int | None = None
    """State rows compared, when the right-hand run ends early (the rows after it were not checked)."""

    def text(self, row: int) -> list[str]:
        step = "reset" if row == 0 else f"step {row - 1}"
        lines = [f"{step} of {self.steps}" + (", success" if self._success(row) else "")]
        if self.verdict and self.checked_rows is not None and row >= self.checked_rows:
            lines.append(f"{self.verdict}: this step not checked (the right-hand run ended)")
        elif self.verdict and self.out_at is None:
            lines.append(self.verdict)
        elif self.verdict:
            lines.append(f"{self.verdict}: {self.detail}" if row >= self.out_at else f"{self.verdict}: in tolerance so far")
        return lines

    def _success(self, row: int) -> bool:
        return self.success is not None and row >= 1 and bool(self.success[row - 1])


def _stored_conversion(compare_meta: RecordingMeta, right: Episode, meta: RecordingMeta, path: str | Path,
                       index: int) -> EpisodeProvenance | None:
    """The verdict ``simreel convert`` stored with `right` (`EpisodeMeta.provenance`), when it judged this very
    episode: the compare file is a conversion of the recording `meta` at `path` (`made_from`) and `right` converts
    episode `index`. None otherwise: a conversion of another recording or episode says nothing of this one, which is
    then compared as any other file is."""
    judged = right.meta.provenance
    if judged is None or not judged.verdict or compared_role(compare_meta, meta, path) != "conversion":
        return None
    return judged if judged.source_episode == index else None


def _conversion_labels(left: Episode, conversion: EpisodeProvenance) -> _Labels:
    """The labels of a video of `left` beside its conversion, with the verdict that conversion stored for this
    episode (`_stored_conversion`), in the words `ViewComparison.verdict` uses (``within tolerance``)."""
    labels = _Labels(left.length, success=left.success, verdict=f"conversion {conversion.verdict.replace('_', ' ')}")
    first = conversion.first_exceeded
    if first:
        labels.out_at = int(first["step"]) + (0 if first.get("at") == "reset" else 1)
        labels.detail = f"{first['key']} off by {first['error']:.3g} at step {first['step']}"
    return labels


def _compared_labels(left: Episode, cmp: ViewComparison, subject: str) -> _Labels:
    """The labels of a video of `left` beside an episode compared with it (`cmp`), the verdict said of `subject`
    (what that episode is: `EpisodeRun.subject`); a shorter compared episode is ``incomplete``, and its frames past
    its end say they were not checked."""
    labels = _Labels(left.length, success=left.success, verdict=f"{subject} {cmp.verdict()}")
    if cmp.divergence is not None:
        d = cmp.divergence
        labels.out_at = 0 if d.at == "reset" else d.step + 1
        labels.detail = f"{d.key} off by {d.error:.3g} at step {d.step}"
    elif cmp.unchecked_steps:
        labels.checked_rows = cmp.steps + 1
    return labels


def _draw(image: np.ndarray, lines: list[str]) -> np.ndarray:
    """`lines` in the frame's top-left corner, white on a dark box."""
    from PIL import Image, ImageDraw

    canvas = Image.fromarray(np.ascontiguousarray(image))
    draw = ImageDraw.Draw(canvas, "RGBA")
    height = max(8, min(16, image.shape[0] // 16))
    y = 2
    for line in lines:
        box = draw.textbbox((4, y), line, font_size=height)
        draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill=(0, 0, 0, 160))
        draw.text((4, y), line, fill=(255, 255, 255, 255), font_size=height)
        y = box[3] + 3
    return np.asarray(canvas)


# ------------------------------------------------------------------------------------------------ encoding
def _encode(path: Path, frames: Iterator[np.ndarray], fps: float, *, overwrite: bool) -> int:
    """Write `frames` to the mp4 `path` through a temporary file (`staged_output`): an interrupted run or a full
    disk leaves no half video, and a video another run wrote meanwhile is replaced only with `overwrite`."""
    with staged_output(path, overwrite=overwrite) as partial:
        return _write_mp4(partial, frames, fps, label=path)


def _write_mp4(path: Path, frames: Iterator[np.ndarray], fps: float, *, label: Path) -> int:
    """Encode `frames` into `path` (`simreel.io.h264.H264Writer`) and return how many; `label` is the video's name in
    errors; ffmpeg's warnings of a video that was written go to stderr."""
    import sys

    from simreel.io.h264 import H264Writer

    writer = None
    try:
        for frame in frames:
            if writer is None:
                writer = H264Writer(path, frame.shape, fps, label=label)
            writer.write(frame)
        if writer is None:
            raise ValueError(f"no frames to write to {label}")
        writer, done = None, writer
    except BaseException:
        if writer is not None:
            writer.kill()
        raise
    said = done.close()
    if said:
        print(said, file=sys.stderr)
    return done.frames
