"""The process's global random generators that an unseeded reset draws from, captured and put back.

ManiSkill 3.0.1 draws an episode reset without a seed (enhanced determinism off) from torch's global generator and
from the env's own episode generator (`_batched_episode_rng`, not reseeded: it goes on from the last seeded reset;
the robot's initial joint noise of the table scenes comes from it); a reset that rebuilds the scene draws its
episode seed from the env's main generator (`_batched_main_rng`); and a task may draw from numpy's or Python's
global one too. A recorder reads their states just before such a reset and keeps those the reset consumed
(`consumed_generators`, stored as `EpisodeMeta.reset_generators`); a replay sets them again just before its own reset
of the episode (`recorded_generators`), so the reset remakes the recorded episode bit for bit, everything PhysX and
the controllers keep included, which no restore of a state dict can. Reading a generator's state never draws from
it: the user's generators are left exactly as they were.
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import random
import struct
import zlib
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np

from simreel.errors import MetadataError

__all__ = ["GENERATORS", "capture_generators", "consumed_generators", "recorded_generators"]

_ENV_GENERATORS = {"episode": "_batched_episode_rng", "main": "_batched_main_rng"}
"""The env's own generators captured, by the name stored and ManiSkill's attribute (a `BatchedRNG` of one env)."""

GENERATORS = ("torch", "numpy", "python", *_ENV_GENERATORS)
"""The generators captured: torch's CPU generator, numpy's legacy `np.random` one, Python's `random` (the process's),
and the env's own episode and main generators (`_ENV_GENERATORS`)."""

_NUMPY_TAIL = struct.Struct("<iid")
_PYTHON_TAIL = struct.Struct("<?d")


def _torch_state() -> bytes:
    import torch

    return torch.get_rng_state().numpy().tobytes()


def _set_torch(raw: bytes) -> None:
    import torch

    torch.set_rng_state(torch.from_numpy(np.frombuffer(raw, np.uint8).copy()))


def _numpy_state() -> bytes:
    return _random_state_bytes(np.random)


def _set_numpy(raw: bytes) -> None:
    np.random.set_state(_random_state_dict(raw))


def _python_state() -> bytes:
    version, words, gauss = random.getstate()
    return struct.pack(f"<i{len(words)}I", version, *words) + _PYTHON_TAIL.pack(
        gauss is not None, gauss or 0.0)


def _set_python(raw: bytes) -> None:
    (version,) = struct.unpack("<i", raw[:4])
    words, tail = raw[4 : -_PYTHON_TAIL.size], raw[-_PYTHON_TAIL.size :]
    has_gauss, gauss = _PYTHON_TAIL.unpack(tail)
    random.setstate((version, tuple(int(w) for w in np.frombuffer(words, "<u4")), gauss if has_gauss else None))


def _random_state_bytes(rng: Any) -> bytes:
    """The state of a numpy `RandomState` (or of the `np.random` module, whose `get_state` is its global one's)."""
    state = rng.get_state(legacy=False)
    tail = _NUMPY_TAIL.pack(state["state"]["pos"], state["has_gauss"], state["gauss"])
    return np.asarray(state["state"]["key"], "<u4").tobytes() + tail


def _random_state_dict(raw: bytes) -> dict[str, Any]:
    keys, tail = raw[: -_NUMPY_TAIL.size], raw[-_NUMPY_TAIL.size :]
    pos, has_gauss, gauss = _NUMPY_TAIL.unpack(tail)
    return {"bit_generator": "MT19937", "state": {"key": np.frombuffer(keys, "<u4").astype(np.uint32), "pos": pos},
            "has_gauss": has_gauss, "gauss": gauss}


def _env_generator(env: Any, name: str) -> np.random.RandomState | None:
    """The generator `name` (`_ENV_GENERATORS`) of a one-env ManiSkill env (`env`: unwrapped), or None where it has
    none."""
    rngs = getattr(getattr(env, _ENV_GENERATORS[name], None), "rngs", None)
    if isinstance(rngs, list) and len(rngs) == 1 and isinstance(rngs[0], np.random.RandomState):
        return rngs[0]
    return None


_READ: dict[str, Callable[[], bytes]] = {"torch": _torch_state, "numpy": _numpy_state, "python": _python_state}
_SET: dict[str, Callable[[bytes], None]] = {"torch": _set_torch, "numpy": _set_numpy, "python": _set_python}


def capture_generators(env: Any = None) -> dict[str, bytes]:
    """The state of each generator now, as bytes (reading draws nothing; torch ~5 kB, the others ~2.5 kB): the
    process's, and `env`'s (unwrapped) episode generator where it has one."""
    out = {name: read() for name, read in _READ.items()}
    for name in _ENV_GENERATORS:
        rng = _env_generator(env, name)
        if rng is not None:
            out[name] = _random_state_bytes(rng)
    return out


def consumed_generators(before: Mapping[str, bytes], env: Any = None) -> dict[str, str]:
    """The generators a reset of `env` drew from, each with its state `before` it (`capture_generators`),
    compressed and base64-encoded for an episode's metadata: only those whose state the reset changed."""
    now = capture_generators(env)
    return {name: base64.b64encode(zlib.compress(raw, 1)).decode("ascii")
            for name, raw in before.items() if now.get(name) != raw}


def _decoded(states: Mapping[str, Any]) -> dict[str, bytes]:
    """The raw states of an episode's `reset_generators`; `MetadataError` for a name or a value no simreel wrote."""
    out = {}
    for name, text in states.items():
        if name not in GENERATORS or not isinstance(text, str):
            raise MetadataError(f"episode metadata: reset_generators holds {name!r}, expected states of "
                                f"{', '.join(GENERATORS)} as base64 text")
        try:
            out[name] = zlib.decompress(base64.b64decode(text, validate=True))
        except (binascii.Error, zlib.error, ValueError) as exc:
            raise MetadataError(f"episode metadata: reset_generators[{name!r}] does not decode ({exc}); the file's "
                                "metadata is damaged") from exc
    return out


@contextlib.contextmanager
def recorded_generators(states: Mapping[str, Any], env: Any = None) -> Iterator[None]:
    """Within the block, the generators named in `states` (an episode's `reset_generators`) hold their recorded
    states: the process's, and those of `env` (unwrapped). Afterwards the process's hold what they held before, so
    its own draws go on unchanged; `env`'s go on from what the block drew, as the recorder's did.
    `MetadataError` (before anything is set) for states that do not decode or a generator refuses."""
    raw = _decoded(states)
    if not raw:
        yield
        return
    saved = capture_generators()
    try:
        for name, value in raw.items():
            _set_recorded(name, value, env)
        yield
    finally:
        for name, value in saved.items():
            _SET[name](value)


def _set_recorded(name: str, value: bytes, env: Any) -> None:
    """Set generator `name` to its recorded state `value` (one of the env's: `env`'s, where it has it)."""
    try:
        if name in _SET:
            _SET[name](value)
            return
        rng = _env_generator(env, name)
        if rng is not None:
            rng.set_state(_random_state_dict(value))
    except (ValueError, TypeError, RuntimeError, struct.error) as exc:
        raise MetadataError(f"episode metadata: reset_generators[{name!r}] is not a state of that generator "
                            f"({exc}); the file's metadata is damaged") from exc
