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
and each input's versions are kept in the output's provenance.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from simreel.episode import RecordingMeta
from simreel.errors import EnvMismatchError

__all__ = ["PROVENANCE_FIELDS", "PHYSICS_NEUTRAL_VERSIONS", "env_definition", "first_difference", "check_same_env"]

PROVENANCE_FIELDS = ("created_utc", "command", "source", "provenance", "format_version")
"""`RecordingMeta` fields that say how and when a file was made, not what its env is: they may differ between
recordings that are merged (each input's are kept in the output's provenance). `format_version` is the layout of
the file read, which the output does not inherit (it is written in the current one)."""
PHYSICS_NEUTRAL_VERSIONS = ("simreel",)
"""Entries of `RecordingMeta.versions` that do not change the physics."""
_ABSENT = "<absent>"


def env_definition(meta: RecordingMeta) -> dict[str, Any]:
    """What defines `meta`'s env and arrays, as JSON: every field but `PROVENANCE_FIELDS`, and the versions but
    `PHYSICS_NEUTRAL_VERSIONS`."""
    d = {k: v for k, v in meta.to_json().items() if k not in PROVENANCE_FIELDS}
    d["versions"] = {k: v for k, v in d.get("versions", {}).items() if k not in PHYSICS_NEUTRAL_VERSIONS}
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


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


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
                f"{label} records another env than {first_label}: {path} is {_shown(got)} there, {_shown(expected)} "
                f"in {first_label}; only recordings of one env (same settings, layouts and simulator versions) "
                "become one file"
            )
