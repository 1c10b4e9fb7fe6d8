"""Log a prepared `ViewSession` into a Rerun recording stream: static geometry first, then each run's poses
(and, for the recording, its contact arrows) in blocks of rows, the recording's camera frames read from its file a
block at a time, then the plots and events.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from simreel.formats.base import block_rows
from simreel.viewers.log_cameras import camera_streams, log_camera_block, log_camera_formats
from simreel.viewers.log_contacts import active_channels, log_contact_block, log_contact_styles
from simreel.viewers.log_plots import (
    episode_events,
    log_contact_magnitudes,
    log_errors,
    log_events,
    log_qpos,
    log_step_plots,
    time_indexes,
)
from simreel.viewers.log_scene import log_geometry, log_pose_block, log_static_poses
from simreel.viewers.paths import REPLAYED, WORLD
from simreel.viewers.poses import PoseSource

if TYPE_CHECKING:
    import rerun as rr

    from simreel.viewers.session import ViewSession
    from simreel.viewers.sources import EpisodeRun

__all__ = ["log_session"]


class _SessionLogger:
    """What logging one session needs beyond the session: body masks and the contact channels' bodies."""

    def __init__(self, rec: rr.RecordingStream, session: ViewSession) -> None:
        self.rec = rec
        self.session = session
        self.episode = session.episode
        self.period = session.period
        names = [b.name for b in session.bodies]
        self.moving = np.array([b.body_type != "static" for b in session.bodies], bool)
        self.moving_names = [n for n, m in zip(names, self.moving, strict=True) if m]
        self.static_names = [n for n, m in zip(names, self.moving, strict=True) if not m]
        self.channels = list(session.meta.contact_channels)
        forces = self.episode.contact_forces
        self.forces = forces
        self.active = active_channels(forces) if forces is not None else np.zeros(len(self.channels), bool)
        index = {n: j for j, n in enumerate(names)}
        self.channel_body = np.array([index.get(ch.bodies[0], -1) for ch in self.channels], np.intp)
        self.streams = camera_streams(session.recording.rows.fields)
        self.block_steps = session.block_steps or block_rows(session.recording.rows.fields)

    def static(self) -> None:
        import rerun as rr

        rec, session = self.rec, self.session
        rec.send_recording_name(session.recording.label)
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        markers = [b.name for b in session.bodies if b.group == "actor"]
        log_geometry(rec, WORLD, session.geometry, markers=markers)
        if session.replayed is not None:
            log_geometry(rec, REPLAYED, session.geometry, ghost=True)
        log_contact_styles(rec, [(c, ch) for c, ch in enumerate(self.channels) if self.active[c]])
        log_camera_formats(rec, self.streams)

    def timeline(self, root: str, run: EpisodeRun) -> bool:
        """Log `run`'s poses under `root` (for the recording also its images and contacts), block by block;
        returns whether the poses came from the recording (else from restored states)."""
        session = self.session
        src = PoseSource(session.env.unwrapped, session.bodies, run.episode.env_states,
                         recorded=run.episode.body_poses, recorded_names=run.meta.pose_bodies)
        total = run.episode.length + 1
        for start in range(0, total, self.block_steps):
            rows = slice(start, min(total, start + self.block_steps))
            poses = src.rows(rows.start, rows.stop)
            if start == 0 and self.static_names:
                log_static_poses(self.rec, root, self.static_names, poses[0, ~self.moving])
            indexes = time_indexes(np.arange(rows.start, rows.stop), self.period)
            log_pose_block(self.rec, root, self.moving_names, poses[:, self.moving], indexes)
            if root == WORLD:
                self._recording_block(rows, poses, indexes)
        return src.from_recording

    def cameras(self) -> None:
        """The recording's camera frames, read from its file and logged a block of rows at a time."""
        if not self.streams:
            return
        run = self.session.recording
        names = [f.name for f in self.streams.values()]
        reset = run.rows.reset()
        log_camera_block(self.rec, reset.arrays, self.streams, time_indexes(np.arange(1), self.period))
        for start, block in run.blocks(run.episode.length, self.block_steps):
            rows = np.arange(start + 1, start + 1 + block.rows)
            log_camera_block(self.rec, {n: block[n] for n in names}, self.streams, time_indexes(rows, self.period))

    def _recording_block(self, rows: slice, poses: np.ndarray, indexes: list[Any]) -> None:
        if self.forces is None or not self.active.any():
            return
        first = max(rows.start, 1)  # contacts of step k go with state row k + 1
        if first >= rows.stop:
            return
        block = poses[first - rows.start :]
        origins = np.full((len(block), len(self.channels), 3), np.nan, np.float32)
        known = self.channel_body >= 0
        origins[:, known] = block[:, self.channel_body[known], :3]
        active = [(c, ch) for c, ch in enumerate(self.channels) if self.active[c]]
        log_contact_block(self.rec, active, self.forces[first - 1 : rows.stop - 1], origins,
                          time_indexes(np.arange(first, rows.stop), self.period))

    def plots(self) -> None:
        rec, session, ep, period = self.rec, self.session, self.episode, self.period
        log_step_plots(rec, ep, period)
        log_qpos(rec, ep.env_states, session.joint_names, period)
        if self.forces is not None:
            log_contact_magnitudes(rec, [(c, ch) for c, ch in enumerate(self.channels) if self.active[c]],
                                   self.forces, period)
        if session.comparison is not None:
            log_errors(rec, session.comparison, period)
        label = session.replayed.label if session.replayed is not None else None
        events = episode_events(ep, channels=self.channels, comparison=session.comparison, compare_label=label,
                                explanation=session.explanation)
        log_events(rec, events, period)


def log_session(rec: rr.RecordingStream, session: ViewSession) -> None:
    """Log the whole session into `rec` (whatever its sink); sets `session.pose_source` and its log time."""
    t0 = time.perf_counter()
    logger = _SessionLogger(rec, session)
    logger.static()
    from_recording = logger.timeline(WORLD, session.recording)
    logger.cameras()
    if session.replayed is not None:
        logger.timeline(REPLAYED, session.replayed)
    session.pose_source = "recorded" if from_recording else "restored"
    logger.plots()
    session.timings["log_s"] = time.perf_counter() - t0
