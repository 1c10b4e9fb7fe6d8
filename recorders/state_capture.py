"""How the recorder reads an env's state (`StateCapture`): through a fast reader of the CPU sim's packed PhysX state
where it is proven equal, bit for bit, to ``get_state_dict()`` (`simreel.sim.state.FastStateReader`), else through
``get_state_dict()`` itself; and the check, at every reset, that the state is in the recording's layout."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np

from simreel.model.meta import RecordingMeta
from simreel.model.state_tree import layout_of
from simreel.sim.state import FastStateReader, check_same_layout, read_state
from simreel.sim.step_rows import PackedRows

__all__ = ["StateCapture"]


class StateCapture:
    """The state reads of one recorder's env `u`, whose recording `meta` keeps the state in its `state_layout`."""

    def __init__(self, u: Any, meta: RecordingMeta) -> None:
        self._u, self._meta = u, meta
        self.fast: FastStateReader | None = None
        self.rows: PackedRows | None = None
        """The row source of the fast reader's captures, its leaves named as the recording's fields."""
        self._unchecked = False
        self._refuted = False
        self._proven_scene: Any = None
        """The PhysX scene whose fast reader passed the check after a step (None: none yet, or rebuilt)."""

    def at_reset(self, reconfigured: bool) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], bytes | None]:
        """The state after a reset (which `reconfigured` the scene or not), read through ``get_state_dict()`` and its
        layout checked: (the state, its leaves the fast reader's capture does not hold, that capture or None)."""
        state = read_state(self._u)
        packed = self._bind(state, reconfigured)
        return state, self._check_layout(state, packed), packed

    def _bind(self, state: dict[str, np.ndarray], reconfigured: bool) -> bytes | None:
        """Bind a fast state reader to the scene after a reset (a reconfiguring reset builds new bodies); the reader's
        capture of `state` where it is the scene's proven reader, kept (else None).

        A reader is checked bit for bit against `get_state_dict()` after the first step of an episode (`after_step`; after
        a reset most velocities are zero, a weaker check), and any difference retires it. Once a scene's reader has
        passed that check, the readers of its later episodes are checked at their reset instead, against `state` (the
        reset row just read through `get_state_dict()`): one fast read rather than one more `get_state_dict()` per
        episode. A reader that differs there is rebuilt and checked after the first step again."""
        if self._refuted:
            return None
        px = self._u.scene.px
        if reconfigured:
            self._proven_scene = None
        kept = self.fast is not None and self.fast.px is px and self._proven_scene is px
        packed = self.fast.capture_equal_to(state) if kept else None
        if packed is not None:  # the scene's proven reader, checked again
            self._unchecked = False
            return packed
        self.fast = FastStateReader.for_env(self._u)
        self._unchecked = self.fast is not None
        if self.fast is not None:
            self.rows = dataclasses.replace(self.fast.packed_rows, prefix="env_states/")
        return None

    def _check_layout(self, state: dict[str, np.ndarray], packed: bytes | None) -> dict[str, np.ndarray]:
        """Refuse a reset whose state (just read through `get_state_dict()`) is not in the recording's layout
        (`StateLayoutError` naming the leaves); returns the leaves of `state` that `packed`, the scene's proven reader's
        capture of it (`_bind`), does not hold: all of them without one. The leaves the capture holds
        need no check: they equal, bit for bit, those of the same reader at a reset whose layout was checked whole
        (when it was built); the others (controller targets, custom state) may change at any reset."""
        layout = self._meta.state_layout
        if packed is not None:
            held = self.fast.packed_keys
            state = {key: a for key, a in state.items() if key not in held}
            layout = {key: spec for key, spec in layout.items() if key not in held}
        check_same_layout(self._meta.env_id, layout, layout_of(state, batched=True))
        return state

    def after_step(self) -> tuple[dict[str, np.ndarray], bytes | None]:
        """The state after a step: (state leaves read now, the packed rest for `rows` or None). Through the
        fast CPU reader where it is proven equal (`_bind`), else all of it through `get_state_dict()`."""
        if self.fast is None:
            return read_state(self._u), None
        if self._unchecked:
            self._unchecked = False
            if not self.fast.matches():
                self.fast, self._refuted = None, True
                warnings.warn(f"simreel: the fast state reader disagrees with {self._meta.env_id}'s get_state_dict(); "
                              "recording through get_state_dict() from now on", RuntimeWarning, stacklevel=3)
                return read_state(self._u), None
            self._proven_scene = self._u.scene.px
        packed = self.fast.capture()
        if packed is None:  # bodies were added or removed since the reader was built
            return read_state(self._u), None
        return self.fast.extras(), packed
