"""Contact forces as arrows at their bodies, present only at steps where the force is non-zero.

Arrow length grows with the logarithm of the force so that a 0.6 N resting contact and a 60 N push are
both readable: ``length = ARROW_SCALE_M × log2(1 + |F| / 1 N)`` (0.6 N → 3.4 cm, 10 N → 17 cm, 100 N →
33 cm), along the force. Each arrow is labelled with its magnitude in newtons.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from simreel.model.meta import ContactChannel
from simreel.verdicts.divergence import CONTACT_THRESHOLD_N
from simreel.viewers.paths import contact_path

__all__ = ["FORCE_THRESHOLD_N", "ARROW_SCALE_M", "ActiveChannels", "arrow_vectors", "active_channels", "log_contact_block",
           "log_contact_styles"]

FORCE_THRESHOLD_N = CONTACT_THRESHOLD_N
"""Forces at or below this magnitude count as no contact: no arrow is drawn (the core's rule)."""
ARROW_SCALE_M = 0.05
_COLORS = {"net": (255, 140, 0, 255), "pair": (230, 40, 200, 255)}
_RADIUS = 0.003


def arrow_vectors(forces: np.ndarray) -> np.ndarray:
    """(N, 3) forces in newtons → (N, 3) arrow vectors in metres (log-scaled length, same direction)."""
    mag = np.linalg.norm(forces, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(mag > 0, forces / mag, 0.0)
    return (unit * ARROW_SCALE_M * np.log2(1.0 + mag)).astype(np.float32)


def active_channels(forces: np.ndarray) -> np.ndarray:
    """(C,) bool: channels whose force exceeds the threshold at some step of (T, C, 3) `forces`."""
    if forces.size == 0:
        return np.zeros(forces.shape[1] if forces.ndim == 3 else 0, bool)
    return (np.linalg.norm(forces, axis=-1) > FORCE_THRESHOLD_N).any(axis=0)


ActiveChannels = Sequence[tuple[int, ContactChannel]]
"""The channels that ever carry a force, each with its column c in the (T, C, 3) force array."""


def log_contact_block(rec: rr.RecordingStream, channels: ActiveChannels, forces: np.ndarray, origins: np.ndarray,
                      indexes: list[rr.TimeColumn]) -> None:
    """Arrows of `channels` for R steps: `forces` (R, C, 3) N, `origins` (R, C, 3) m (NaN: unknown body).

    Each step's row holds one arrow when the force is non-zero, none otherwise (which clears the arrow).
    """
    mags = np.linalg.norm(forces, axis=-1)
    for c, channel in channels:
        on = (mags[:, c] > FORCE_THRESHOLD_N) & np.isfinite(origins[:, c]).all(axis=1)
        f = forces[on, c]
        labels = [f"{m:.2f} N" for m in mags[on, c]]
        columns = rr.Arrows3D.columns(
            vectors=arrow_vectors(f).reshape(-1, 3), origins=origins[on, c].reshape(-1, 3), labels=labels
        ).partition(on.astype(np.int64))
        rec.send_columns(contact_path(channel.kind, channel.bodies), indexes=indexes, columns=columns)


def log_contact_styles(rec: rr.RecordingStream, channels: ActiveChannels) -> None:
    """Colour and radius of each active channel's arrows, static (they apply to every step's arrow)."""
    for _, channel in channels:
        rec.log(contact_path(channel.kind, channel.bodies),
                rr.Arrows3D.from_fields(colors=[_COLORS.get(channel.kind, (255, 255, 255, 255))], radii=[_RADIUS]),
                static=True)
