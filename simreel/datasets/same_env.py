"""The one rule for "recordings of the same env": what several recordings must share to become one file.

A recording's `RecordingMeta` says how to rebuild its env and what its episodes' arrays are. Two recordings are
of the same env when every field of it is equal but the provenance ones below: env id and gym.make kwargs,
obs/control/reward mode, sim and render backend, num_envs (GPU results depend on it), time limit, control and
sim frequency, sim config, action space, the state/obs/info layouts, the scene, contact channels, pose bodies,
the `--import` specs, what the file does not hold (`unknown`), and the versions of everything that simulates
(mani_skill, sapien, torch, numpy, python). A field added to `RecordingMeta` later is part of the env unless it
is listed here: the safe default.

Versions are part of the env on purpose: a merged file carries one `versions`, which a replay compares with the
replaying machine's; episodes recorded by other ManiSkill/SAPIEN/torch builds would be judged against a build
that did not record them. So recordings of different builds are not merged (keep them in separate files); only
simreel's own version may differ, as it does not change the physics (the replay fingerprint ignores it too),
and each input's versions are kept in the output's provenance. Likewise ``render_mode`` may differ (it chooses what
``env.render()`` returns, not the physics nor the arrays: `PHYSICS_NEUTRAL_ENV_KWARGS`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from simreel.errors import EnvMismatchError
from simreel.model.meta import RecordingMeta

__all__ = ["PROVENANCE_FIELDS", "PHYSICS_NEUTRAL_VERSIONS", "PHYSICS_NEUTRAL_ENV_KWARGS", "env_definition",
           "first_difference", "check_same_env"]

PROVENANCE_FIELDS = ("created_utc", "command", "recording_id", "source", "provenance", "format_version")
"""`RecordingMeta` fields that say how and when a file was made, not what its env is: they may differ between
recordings that are merged (each input's are kept in the output's provenance). `format_version` is the layout of
the file read, which the output does not inherit (it is written in the current one)."""
PHYSICS_NEUTRAL_VERSIONS = ("simreel",)
"""Entries of `RecordingMeta.versions` that do not change the physics."""
PHYSICS_NEUTRAL_ENV_KWARGS = ("render_mode",)
"""Entries of `RecordingMeta.env_kwargs` that change neither the physics nor what a file holds: ``render_mode`` picks
what ``env.render()`` returns (images for videos, a viewer), which neither a recording's arrays nor a replay use
(simreel's replay leaves it out; ManiSkill's replay_trajectory always sets its own, ``rgb_array``, which is how its
outputs come to differ from their sources). Merged inputs may differ in them (see `simreel.datasets.dataset`)."""
_ABSENT = "<absent>"


def env_definition(meta: RecordingMeta) -> dict[str, Any]:
    """What defines `meta`'s env and arrays, as JSON: every field but `PROVENANCE_FIELDS`, the versions but
    `PHYSICS_NEUTRAL_VERSIONS`, the env kwargs but `PHYSICS_NEUTRAL_ENV_KWARGS`."""
    d = {k: v for k, v in meta.to_json().items() if k not in PROVENANCE_FIELDS}
    d["versions"] = {k: v for k, v in d.get("versions", {}).items() if k not in PHYSICS_NEUTRAL_VERSIONS}
    d["env_kwargs"] = {k: v for k, v in d.get("env_kwargs", {}).items() if k not in PHYSICS_NEUTRAL_ENV_KWARGS}
    return d


def first_difference(a: Any, b: Any, path: str = "") -> tuple[str, Any, Any] | None:
    """The first place where JSON values `a` and `b` differ, as (dotted path, value in a, value in b); None when
    equal. Objects are walked in `a`'s key order (then `b`'s extra keys), lists item by item."""
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for key in [*a, *(k for k in b if k not in a)]:
            found = first_difference(a.get(key, _ABSENT), b.get(key, _ABSENT), f"{path}.{key}" if path else str(key))
            if found is not None:
                return found
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            found = first_difference(x, y, f"{path}[{k}]")
            if found is not None:
                return found
        return None
    return None if a == b and type(a) is type(b) else (path, a, b)


_SHOWN_CHARS = 80
"""The longest value a mismatch message shows whole; a longer one is shown by where it differs (`_difference`)."""
_CONTEXT_CHARS = 20
"""How much of a long value a mismatch message shows before the first character where the two differ."""


def _difference(path: str, got: Any, expected: Any, first_label: str) -> str:
    """How `got` (in the recording refused) differs from `expected` (in `first_label`) at `path`, for one line: both
    values when short; for long lists, what each holds that the other lacks; else both cut at the same place,
    just before where they start to differ, so that the difference is never cut off."""
    got_text, expected_text = repr(got), repr(expected)
    if max(len(got_text), len(expected_text)) <= _SHOWN_CHARS:
        return f"{path} is {got_text} there, {expected_text} in {first_label}"
    if isinstance(got, list) and isinstance(expected, list):
        only_there, only_first = [x for x in got if x not in expected], [x for x in expected if x not in got]
        parts = ([f"{_cut(repr(only_there), 0)} there, not in {first_label}"] if only_there else []) + (
            [f"{_cut(repr(only_first), 0)} in {first_label}, not there"] if only_first else [])
        if parts:
            return f"{path} holds {', and '.join(parts)}"
    start = max(0, _common_prefix(got_text, expected_text) - _CONTEXT_CHARS)
    return f"{path} is {_cut(got_text, start)} there, {_cut(expected_text, start)} in {first_label}"


def _common_prefix(a: str, b: str) -> int:
    return next((k for k, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))


def _cut(text: str, start: int) -> str:
    """`text` from `start`, at most `_SHOWN_CHARS` of it, with ``...`` where it was cut."""
    shown = ("..." if start else "") + text[start:]
    return shown if len(shown) <= _SHOWN_CHARS else shown[: _SHOWN_CHARS - 3] + "..."


def check_same_env(recordings: Sequence[tuple[str, RecordingMeta]]) -> None:
    """Raise `EnvMismatchError` unless every (label, meta) records the env of the first: the message names the
    first field that differs and both values."""
    if not recordings:
        return
    first_label, first = recordings[0]
    want = env_definition(first)
    for label, meta in recordings[1:]:
        found = first_difference(want, env_definition(meta))
        if found is not None:
            path, expected, got = found
            raise EnvMismatchError(
                f"{label} records another env than {first_label}: {_difference(path, got, expected, first_label)}; "
                "only recordings of one env (same settings, layouts and simulator versions) become one file"
            )
