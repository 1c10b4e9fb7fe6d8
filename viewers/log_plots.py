"""Time series under ``plots/`` and the text log of episode events (and of a divergence's explanation) under ``events``.

Everything is placed by state row: a quantity of step t (reward, success, info, contact force) goes with
row t + 1, the state that step produced, which the ``step`` timeline shows at t (see `simreel.viewers.paths`).
Multi-column series (a robot's qpos, all contact magnitudes) are one entity each with named series, so each block of
rows is one `send_columns` call; the series' names and colours are logged once, static, with the first block.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import rerun as rr

from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel
from simreel.verdicts.divergence import EpisodeEvent, Explanation
from simreel.verdicts.divergence import episode_events as core_episode_events
from simreel.viewers.compare import ViewComparison, divergence_row
from simreel.viewers.log_contacts import ActiveChannels
from simreel.viewers.paths import EVENTS, SIM_TIME, STEP, plot_path

__all__ = ["time_indexes", "SeriesStyle", "log_series", "log_step_block", "log_qpos_block", "log_contact_magnitudes",
           "log_errors", "Event", "episode_events", "log_events"]

_TOLERANCE_COLOR = (200, 40, 40, 255)
_ERROR_COLORS = ((40, 110, 220, 255), (30, 160, 90, 255), (150, 80, 200, 255), (230, 140, 20, 255),
                 (20, 170, 190, 255), (120, 120, 120, 255))


def _error_color(key: str) -> tuple[int, int, int, int]:
    """A stable colour per state key (not random: the same key has the same colour in every session)."""
    import zlib

    return _ERROR_COLORS[zlib.crc32(key.encode()) % len(_ERROR_COLORS)]


def time_indexes(rows: np.ndarray, period: float | None) -> list[rr.TimeColumn]:
    """Time columns for state rows `rows`: ``step`` = row - 1 (see `simreel.viewers.paths`) and, when the
    control period is known, ``sim_time`` = row × period."""
    rows = np.asarray(rows, np.int64)
    cols = [rr.TimeColumn(STEP, sequence=rows - 1)]
    if period:
        cols.append(rr.TimeColumn(SIM_TIME, duration=rows * float(period)))
    return cols


@dataclass(frozen=True)
class SeriesStyle:
    """Names and colours of a plot's series, logged once (static)."""

    names: Sequence[str] | None = None
    colors: Sequence[tuple[int, int, int, int]] | None = None
    widths: Sequence[float] | None = None


def log_series(rec: rr.RecordingStream, path: str, values: np.ndarray, indexes: list[rr.TimeColumn],
               style: SeriesStyle | None = None) -> None:
    """`values` (R,) or (R, K) at the R time points of `indexes`, with their `style` logged once, static."""
    values = np.asarray(values, np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if style is not None:
        rec.log(path, rr.SeriesLines(names=style.names, colors=style.colors, widths=style.widths), static=True)
    rec.send_columns(path, indexes=indexes, columns=rr.Scalars.columns(scalars=values))


def _style(names: Sequence[str], styled: bool) -> SeriesStyle | None:
    return SeriesStyle(names) if styled else None


def log_step_block(rec: rr.RecordingStream, arrays: Mapping[str, np.ndarray], at: list[rr.TimeColumn], *,
                   styled: bool) -> None:
    """``plots/reward``, ``plots/success`` and ``plots/info/<key>`` (every scalar info entry) of a block of steps:
    `arrays` holds their per-step fields, at the time points `at` of the state rows those steps produced; `styled`:
    the first block, which logs the series' names."""
    if "rewards" in arrays:
        log_series(rec, plot_path("reward"), arrays["rewards"], at, _style(["reward"], styled))
    if "success" in arrays:
        log_series(rec, plot_path("success"), arrays["success"].astype(np.float64), at, _style(["success"], styled))
    for name, values in arrays.items():
        key = name.removeprefix("info/")
        if key == name or key in ("success", "elapsed_steps") or values.ndim != 1:
            continue
        log_series(rec, plot_path("info", key), values.astype(np.float64), at, _style([key], styled))


def log_qpos_block(rec: rr.RecordingStream, arrays: Mapping[str, np.ndarray], at: list[rr.TimeColumn],
                   joint_names: Mapping[str, Sequence[str]], *, styled: bool) -> None:
    """``plots/qpos/<articulation>``: joint positions from the articulation states (13 + 2·DOF floats) of a block of
    state rows at the time points `at` (`arrays`: flat field names)."""
    for name, a in arrays.items():
        key = name.removeprefix("env_states/")
        if not key.startswith("articulations/") or a.ndim != 2 or a.shape[1] < 13:
            continue
        art = key.split("/", 1)[1]
        dof = (a.shape[1] - 13) // 2
        names = list(joint_names.get(art, []))[:dof] or [f"q{i}" for i in range(dof)]
        if not names:
            continue
        log_series(rec, plot_path("qpos", art), a[:, 13 : 13 + len(names)], at, _style(names, styled))


def log_contact_magnitudes(rec: rr.RecordingStream, channels: ActiveChannels, forces: np.ndarray,
                           at: list[rr.TimeColumn], *, styled: bool) -> None:
    """``plots/contacts/net`` and ``plots/contacts/pair``: |F| in newtons of every channel that is ever non-zero, for
    a block of steps (`forces` (R, C, 3), at the time points `at` of the state rows they produced)."""
    if forces is None or not len(forces):
        return
    mags = np.linalg.norm(forces, axis=-1)
    for kind in ("net", "pair"):
        picked = [(c, ch) for c, ch in channels if ch.kind == kind]
        if picked:
            log_series(rec, plot_path("contacts", kind), mags[:, [c for c, _ in picked]], at,
                       _style([ch.name for _, ch in picked], styled))


def log_errors(rec: rr.RecordingStream, comparison: ViewComparison, period: float | None) -> None:
    """``plots/error/<key>``: the compared episode's error per key (as `simreel replay` computes it) beside its
    tolerance, a flat line. The keys plotted are `ViewComparison.plotted_keys`: those ever off, else the state keys."""
    rows_by_key = comparison.error_rows()
    first = comparison.divergence.key if comparison.divergence is not None else None
    for key in comparison.plotted_keys():
        rows, err, tol = rows_by_key[key]
        values = np.stack([np.where(np.isfinite(err), err, np.nan), np.full(len(err), tol)], axis=1)
        style = SeriesStyle([key, "tolerance"], [_error_color(key), _TOLERANCE_COLOR], [3.0 if key == first else 1.5, 1.0])
        log_series(rec, plot_path("error", key), values, time_indexes(rows, period), style)


@dataclass(frozen=True)
class Event:
    """One line of the ``events`` text log."""

    row: int
    """The state row it belongs to (the `step` timeline shows row r at r - 1)."""
    level: str
    text: str


_EVENT_LEVELS = {"contact_begins": "DEBUG", "contact_ends": "DEBUG", "success_lost": "WARN", "fail": "WARN",
                 "controller_jump": "WARN"}
"""Text-log level of each `simreel.verdicts.divergence.EpisodeEvent` kind (INFO for the others)."""


def _row(step: int) -> int:
    """The state row of a step's outcome (step -1, the reset: row 0)."""
    return step + 1


def _episode_event(e: EpisodeEvent) -> Event:
    text = e.describe().split(": ", 1)[1]  # the timeline says the step
    return Event(_row(e.step), _EVENT_LEVELS.get(e.kind, "INFO"), text)


def _explanation_events(explanation: Explanation) -> list[Event]:
    """The explanation's lines at the steps they are about: why (at the divergence), error growth (where each key left
    its tolerance), the onset of the state difference."""
    d = explanation.divergence
    row = divergence_row(d)
    out = []
    if explanation.cause is not None:
        out.append(Event(row, "ERROR", f"why: {explanation.cause.summary}"))
        out += [Event(row, "WARN", f"why: {line}") for line in explanation.cause.evidence]
    else:
        out += [Event(row, "WARN", f"why: {line}") for line in explanation.checked]
    out += [Event(_row(g.step), "WARN", f"error: {g.describe()}") for g in explanation.growth]
    if explanation.onset is not None:
        out.append(Event(_row(explanation.onset.step), "WARN", f"onset: {explanation.onset.describe()}"))
    return out


def episode_events(
    episode: Episode,
    *,
    channels: Sequence[ContactChannel] = (),
    comparison: ViewComparison | None = None,
    compared: tuple[str, str] | None = None,
    explanation: Explanation | None = None,
) -> list[Event]:
    """Start, the episode's events (`simreel.verdicts.divergence.episode_events`: contacts with their force, grasps, success,
    controller jumps, termination), the first divergence and its explanation. `compared`: the compared episode's
    label and subject (`simreel.viewers.sources.EpisodeRun`), what the comparison's lines call it."""
    m = episode.meta
    start = f"episode {m.index} starts (seed {m.seed}, env {m.env_idx}, {episode.length} steps)"
    events = [Event(0, "INFO", start), *(Event(0, "WARN", note) for note in m.notes)]
    events += [_episode_event(e) for e in core_episode_events(episode, channels)]
    if comparison is not None:
        label, subject = compared or ("the compared episode", "compared episode")
        events.append(Event(0, "INFO", f"compared with {label}: {comparison.verdict()}"))
        if comparison.note:
            events.append(Event(0, "WARN", comparison.note))
        d = comparison.divergence
        if d is not None:
            events.append(Event(divergence_row(d), "ERROR", d.sentence(f"{subject} diverges")))
    if explanation is not None:
        events += _explanation_events(explanation)
    order = {"ERROR": 0, "WARN": 1}
    return sorted(events, key=lambda e: (e.row, order.get(e.level, 2)))


def log_events(rec: rr.RecordingStream, events: Sequence[Event], period: float | None) -> None:
    """The events as one ``TextLog`` column under ``events``."""
    if not events:
        return
    rec.send_columns(
        EVENTS,
        indexes=time_indexes(np.array([e.row for e in events]), period),
        columns=rr.TextLog.columns(text=[e.text for e in events], level=[e.level for e in events]),
    )
