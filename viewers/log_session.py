"""Log a prepared `ViewSession` into a Rerun recording stream: static geometry first, then each run read from its
file a block of rows at a time (`EpisodeRun.row_blocks`), each block's poses (and, for the recording, its camera
frames, contact arrows and plots) sent with `send_columns` before the next is read, then the comparison's error
curves and the events.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from simreel.viewers.log_cameras import camera_streams, log_camera_block, log_camera_formats
from simreel.viewers.log_contacts import active_channels, log_contact_block, log_contact_styles
from simreel.viewers.log_plots import (
    episode_events,
    log_contact_magnitudes,
    log_errors,
    log_events,
    log_qpos_block,
    log_step_block,
    time_indexes,
)
from simreel.viewers.log_scene import log_geometry, log_pose_block, log_static_poses
from simreel.viewers.paths import COMPARED, WORLD
from simreel.viewers.poses import PoseSource

if TYPE_CHECKING:
    import rerun as rr

    from simreel.viewers.session import ViewSession
    from simreel.viewers.sources import EpisodeRun

__all__ = ["log_session"]


def _states(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k.removeprefix("env_states/"): a for k, a in arrays.items() if k.startswith("env_states/")}


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
        self.active_list = [(c, ch) for c, ch in enumerate(self.channels) if self.active[c]]
        index = {n: j for j, n in enumerate(names)}
        self.channel_body = np.array([index.get(ch.bodies[0], -1) for ch in self.channels], np.intp)
        self.streams = camera_streams(session.recording.rows.fields)

    def static(self) -> None:
        import rerun as rr

        rec, session = self.rec, self.session
        rec.send_recording_name(session.recording.label)
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        markers = [b.name for b in session.bodies if b.group == "actor"]
        log_geometry(rec, WORLD, session.geometry, markers=markers)
        if session.compared is not None:
            log_geometry(rec, COMPARED, session.geometry, ghost=True)
        log_contact_styles(rec, self.active_list)
        log_camera_formats(rec, self.streams)

    def timeline(self, root: str, run: EpisodeRun) -> bool:
        """Log `run` under `root` a block of rows at a time: its poses, and for the recording also its camera
        frames, contacts and plots; returns whether the poses came from the recording (else from restored states)."""
        session = self.session
        from_recording = True
        for first, arrays in run.row_blocks(session.block_steps):
            src = PoseSource(session.env.unwrapped, session.bodies, _states(arrays), recorded=arrays.get("body_poses"),
                             recorded_names=run.meta.pose_bodies)
            from_recording = src.from_recording
            rows = np.arange(first, first + len(next(iter(arrays.values()))))
            poses = src.rows(0, len(rows))
            if first == 0 and self.static_names:
                log_static_poses(self.rec, root, self.static_names, poses[0, ~self.moving])
            indexes = time_indexes(rows, self.period)
            log_pose_block(self.rec, root, self.moving_names, poses[:, self.moving], indexes)
            if root == WORLD:
                self._recording_block(rows, arrays, poses, indexes)
        return from_recording

    def _recording_block(self, rows: np.ndarray, arrays: Mapping[str, np.ndarray], poses: np.ndarray,
                         indexes: list[rr.TimeColumn]) -> None:
        if self.streams:
            log_camera_block(self.rec, arrays, self.streams, indexes)
        log_qpos_block(self.rec, arrays, indexes, self.session.joint_names, styled=rows[0] == 0)
        if rows[0] == 0:  # the reset: no step yet
            return
        log_step_block(self.rec, arrays, indexes, styled=rows[0] == 1)
        forces = arrays.get("contact_forces")
        if forces is None:
            return
        log_contact_magnitudes(self.rec, self.active_list, forces, indexes, styled=rows[0] == 1)
        if not self.active.any():
            return
        # contacts of step k go with state row k + 1, at the bodies' poses there
        origins = np.full((len(rows), len(self.channels), 3), np.nan, np.float32)
        known = self.channel_body >= 0
        origins[:, known] = poses[:, self.channel_body[known], :3]
        log_contact_block(self.rec, self.active_list, forces, origins, indexes)

    def plots(self) -> None:
        rec, session, ep, period = self.rec, self.session, self.episode, self.period
        if session.comparison is not None:
            log_errors(rec, session.comparison, period)
        compared = session.compared
        events = episode_events(ep, channels=self.channels, comparison=session.comparison,
                                compared=None if compared is None else (compared.label, compared.subject),
                                explanation=session.explanation)
        log_events(rec, events, period)


def log_session(rec: rr.RecordingStream, session: ViewSession) -> None:
    """Log the whole session into `rec` (whatever its sink); sets `session.pose_source` and its log time."""
    t0 = time.perf_counter()
    logger = _SessionLogger(rec, session)
    logger.static()
    from_recording = logger.timeline(WORLD, session.recording)
    if session.compared is not None:
        logger.timeline(COMPARED, session.compared)
    session.pose_source = "recorded" if from_recording else "restored"
    logger.plots()
    session.timings["log_s"] = time.perf_counter() - t0
