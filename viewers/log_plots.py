"""Time series under ``plots/`` and the text log of episode events under ``events``.

Everything is placed by state row: a quantity of step t (reward, success, info, contact force) goes with
row t + 1, the state that step produced, which the ``step`` timeline shows at t (see `simreel.viewers.paths`). Multi-column series (a robot's qpos, all contact
magnitudes) are one entity each with named series, so each is one `send_columns` call.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import rerun as rr

from simreel.episode import ContactChannel, Episode
from simreel.viewers.compare import ViewComparison, divergence_row
from simreel.viewers.log_contacts import FORCE_THRESHOLD_N, ActiveChannels
from simreel.viewers.paths import EVENTS, SIM_TIME, STEP, plot_path

__all__ = ["time_indexes", "SeriesStyle", "log_series", "log_step_plots", "log_qpos", "log_contact_magnitudes", "log_errors",
           "Event", "episode_events", "log_events"]

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


def log_step_plots(rec: rr.RecordingStream, episode: Episode, period: float | None) -> None:
    """``plots/reward``, ``plots/success`` and ``plots/info/<key>`` for every scalar info entry."""
    T = episode.length
    if T == 0:
        return
    at = time_indexes(np.arange(1, T + 1), period)
    if episode.rewards is not None:
        log_series(rec, plot_path("reward"), episode.rewards, at, SeriesStyle(["reward"]))
    if episode.success is not None:
        log_series(rec, plot_path("success"), episode.success.astype(np.float64), at, SeriesStyle(["success"]))
    for key, values in episode.info.items():
        if key in ("success", "elapsed_steps") or values.ndim != 1:
            continue
        log_series(rec, plot_path("info", key), values.astype(np.float64), at, SeriesStyle([key]))


def log_qpos(
    rec: rr.RecordingStream, states: Mapping[str, np.ndarray], joint_names: Mapping[str, Sequence[str]],
    period: float | None,
) -> None:
    """``plots/qpos/<articulation>``: joint positions from the articulation states (13 + 2·DOF floats)."""
    for key, a in states.items():
        if not key.startswith("articulations/") or a.ndim != 2 or a.shape[1] < 13:
            continue
        art = key.split("/", 1)[1]
        dof = (a.shape[1] - 13) // 2
        names = list(joint_names.get(art, []))[:dof] or [f"q{i}" for i in range(dof)]
        if not names:
            continue
        log_series(rec, plot_path("qpos", art), a[:, 13 : 13 + len(names)], time_indexes(np.arange(len(a)), period),
                   SeriesStyle(names))


def log_contact_magnitudes(rec: rr.RecordingStream, channels: ActiveChannels, forces: np.ndarray,
                           period: float | None) -> None:
    """``plots/contacts/net`` and ``plots/contacts/pair``: |F| in newtons of every channel that is ever non-zero."""
    if forces is None or not len(forces):
        return
    mags = np.linalg.norm(forces, axis=-1)
    at = time_indexes(np.arange(1, len(forces) + 1), period)
    for kind in ("net", "pair"):
        picked = [(c, ch) for c, ch in channels if ch.kind == kind]
        if picked:
            log_series(rec, plot_path("contacts", kind), mags[:, [c for c, _ in picked]], at,
                       SeriesStyle([ch.name for _, ch in picked]))


def log_errors(rec: rr.RecordingStream, comparison: ViewComparison, period: float | None) -> None:
    """``plots/error/<key>``: the replay's error per compared key (as `simreel replay` computes it) beside its
    tolerance, a flat line. State keys are always plotted; other keys only when they are ever off."""
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


def _transitions(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into `flags`) where a bool series turns on and where it turns off."""
    f = np.asarray(flags, bool).astype(np.int8)
    d = np.diff(np.concatenate([[0], f]))
    return np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]


def episode_events(
    episode: Episode,
    *,
    channels: Sequence[ContactChannel] = (),
    comparison: ViewComparison | None = None,
    compare_label: str | None = None,
) -> list[Event]:
    """Start, success on/off, pair contacts beginning/ending, termination/truncation, first divergence."""
    m = episode.meta
    start = f"episode {m.index} starts (seed {m.seed}, env {m.env_idx}, {episode.length} steps)"
    events = [Event(0, "INFO", start), *(Event(0, "WARN", note) for note in m.notes)]
    if episode.success is not None:
        on, off = _transitions(episode.success)
        events += [Event(int(t) + 1, "INFO", f"success at step {int(t)}") for t in on]
        events += [Event(int(t) + 1, "WARN", f"success lost at step {int(t)}") for t in off]
    if episode.contact_forces is not None and len(episode.contact_forces):
        touching = np.linalg.norm(episode.contact_forces, axis=-1) > FORCE_THRESHOLD_N
        for c, ch in enumerate(channels):
            if ch.kind != "pair":
                continue
            on, off = _transitions(touching[:, c])
            events += [Event(int(t) + 1, "DEBUG", f"contact {ch.name} begins") for t in on]
            events += [Event(int(t) + 1, "DEBUG", f"contact {ch.name} ends") for t in off]
    for flag in ("terminated", "truncated"):
        hits = np.nonzero(np.asarray(getattr(episode, flag), bool))[0]
        if len(hits):
            events.append(Event(int(hits[0]) + 1, "INFO", f"{flag} at step {int(hits[0])}"))
    if comparison is not None:
        label = compare_label or "the replay"
        verdict = comparison.comparison.verdict.replace("_", " ")
        events.append(Event(0, "INFO", f"compared with {label}: {verdict}"))
        if comparison.note:
            events.append(Event(0, "WARN", comparison.note))
        d = comparison.divergence
        if d is not None:
            text = d.describe() if d.at == "reset" else f"at {d.describe()}"
            events.append(Event(divergence_row(d), "ERROR", f"replay diverges {text}"))
    return sorted(events, key=lambda e: (e.row, e.level != "ERROR"))


def log_events(rec: rr.RecordingStream, events: Sequence[Event], period: float | None) -> None:
    """The events as one ``TextLog`` column under ``events``."""
    if not events:
        return
    rec.send_columns(
        EVENTS,
        indexes=time_indexes(np.array([e.row for e in events]), period),
        columns=rr.TextLog.columns(text=[e.text for e in events], level=[e.level for e in events]),
    )
