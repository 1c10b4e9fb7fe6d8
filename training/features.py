"""Features chosen by name: a field of the recording's field table (`obs/agent/qpos`, `env_states/actors/cube`'s
leaves, `actions`, `rewards`, `success`, `contact_forces`, ...) or a group of them (`obs`, `env_states/actors/cube`:
every leaf below it), resolved against each file's table; a name a file lacks is an error naming the file and the
episode, with how to come by a recording that has it (no silent empty observation)."""

from __future__ import annotations

from collections.abc import Sequence

from simreel.errors import RecordingFileError, UsageError
from simreel.model.fields import FieldSpec

__all__ = ["resolve_features", "same_features"]

_HOW_TO_HAVE = {
    "obs": "it was recorded without observations: record with --record-obs (RecordWrapper(record_obs=True)), or "
           "`simreel convert` it to an observation mode; or choose state leaves (env_states/...)",
    "env_states": "it holds no env states: record with them (simreel record, RecordEpisode(record_env_state=True))",
    "contact_forces": "it was recorded without contact forces: record with --contacts auto",
    "rewards": "the file holds no rewards",
    "success": "the file holds no success flags",
    "body_poses": "it was recorded without body poses: record with --poses",
}


def resolve_features(names: Sequence[str], fields: Sequence[FieldSpec], *, path: str,
                     episode: int) -> list[FieldSpec]:
    """The fields of `fields` (a file's table) that `names` choose, each once, in the order named (a group's leaves in
    table order); `RecordingFileError` naming `path` and `episode` for a name that chooses none."""
    if isinstance(names, str) or not names:
        raise UsageError(f"features={names!r}: give a list of field names, e.g. ['obs/agent/qpos', 'actions']")
    chosen: dict[str, FieldSpec] = {}
    for name in names:
        if not isinstance(name, str) or not name.strip("/"):
            raise UsageError(f"feature {name!r}: give a field name such as 'obs/agent/qpos' or a group such as 'obs'")
        name = name.strip("/")
        found = [f for f in fields if f.name == name or f.name.startswith(name + "/")]
        if not found:
            raise RecordingFileError(path, f"episode {episode} has no {name} ({_missing_hint(name, fields)})")
        chosen.update((f.name, f) for f in found)
    return list(chosen.values())


def _missing_hint(name: str, fields: Sequence[FieldSpec]) -> str:
    group = name.split("/")[0]
    held = sorted({f.name.split("/")[0] for f in fields})
    why = _HOW_TO_HAVE.get(group, "no field or group of that name")
    if not any(f.name.startswith(group + "/") or f.name == group for f in fields) or group not in _HOW_TO_HAVE:
        return f"{why}; it holds {', '.join(held)}"
    near = [f.name for f in fields if f.name.startswith(group + "/")][:8]
    return f"its {group} fields are {', '.join(near)}{', ...' if len(near) == 8 else ''}"


def same_features(chosen: Sequence[FieldSpec], first: Sequence[FieldSpec], *, path: str, first_path: str) -> None:
    """`UsageError` unless a file's `chosen` fields are those of the first file (names, dtypes, row shapes): one
    training set's samples have one layout."""
    if [(f.name, f.dtype, f.shape, f.per_state) for f in chosen] == [(f.name, f.dtype, f.shape, f.per_state)
                                                                        for f in first]:
        return
    theirs = {f.name: f for f in first}
    for f in chosen:
        other = theirs.get(f.name)
        if other is None or (other.dtype, other.shape) != (f.dtype, f.shape):
            was = "nothing" if other is None else f"{other.dtype} {other.shape}"
            raise UsageError(f"{path}: {f.name} is {f.dtype} {f.shape}, but {first_path} has {was}: the files of one "
                             "read together need the same features; read them separately")
    missing = sorted(set(theirs) - {f.name for f in chosen})
    raise UsageError(f"{path} lacks {', '.join(missing)}, which {first_path} has: the files read together need "
                     "the same features; read them separately")
