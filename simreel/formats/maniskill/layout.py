"""ManiSkill's trajectory-file layout, which simreel's HDF5 recordings share so ManiSkill's own tools read them.

A ManiSkill trajectory file (written by `mani_skill.utils.wrappers.RecordEpisode` and by
`mani_skill.trajectory.replay_trajectory`) is an HDF5 file of groups ``traj_<episode id>`` and a JSON sidecar
``<name>.json`` beside it (`simreel.formats.maniskill.sidecar`). Inside a group:

    actions terminated truncated              (T, ...)   always
    rewards success fail                      (T,)       when recorded / when the task reports them
    env_states/<key path>                     (T+1, ...) when the state was recorded (record_env_state)
    obs                                       (T+1, D)   an observation that is one array (obs_mode "state")
    obs/<key path>                            (T+1, ...) a dict observation (state_dict, rgb, sensor_data, ...)

A field of simreel's table (`simreel.model.fields.episode_fields`) is the dataset of the same name, except a
bare-array observation: simreel names it ``obs/<obs mode>`` (the key `flatten_obs` gives it), ManiSkill stores
it as the dataset ``obs`` itself; `dataset_name` and `field_name` translate.
"""

from __future__ import annotations

import glob
import re
from pathlib import Path

from simreel.errors import UsageError
from simreel.model.meta import RecordingMeta

__all__ = ["group_name", "group_index", "sidecar_path", "refuse_replacing_sidecar", "sidecar_owners", "obs_is_array", "dataset_name",
           "field_name", "maniskill_tools", "OBS"]

OBS = "obs"
_GROUP = re.compile(r"traj_(0|[1-9][0-9]*)")
"""``traj_<index>`` as `group_name` writes it and ManiSkill's tools look it up (``traj_01`` is no episode's group)."""


def group_name(index: int) -> str:
    """The group of episode `index`: ``traj_<index>``."""
    return f"traj_{index}"


def group_index(name: str) -> int | None:
    """The episode index of a group named ``traj_<index>`` (no leading zero); None for any other name."""
    m = _GROUP.fullmatch(name)
    return int(m.group(1)) if m else None


def sidecar_path(path: Path) -> Path:
    """The JSON sidecar beside `path` (`x.h5` → `x.json`), as ManiSkill's tools look for it."""
    return Path(path).with_suffix(".json")


def refuse_replacing_sidecar(file: Path, *, writing: str | Path, own: Path | None = None) -> None:
    """`UsageError` when `file`, which writing `writing` would replace, is the JSON sidecar of an HDF5 file other
    than `own` (`x.json` is the sidecar of `x.h5` and of `x.hdf5`), `--overwrite` or not: ManiSkill's tools read a
    recording with its sidecar, so another recording sharing its name, or a report (`--report`, `--json`), that
    replaced it would leave the recording unreadable to them. Only a sidecar that is there is guarded."""
    file = Path(file)
    if file.suffix != ".json" or not (file.exists() or file.is_symlink()):
        return
    for other in sidecar_owners(file):
        if own is None or other.name != Path(own).name:
            raise UsageError(f"{file} is the JSON sidecar of {other}, which ManiSkill's tools read with it; writing "
                             f"{writing} would replace it: name the output otherwise")


def sidecar_owners(file: Path) -> list[Path]:
    """The HDF5 files beside `file` whose JSON sidecar it is (`x.json` is the sidecar of `x.h5` and of `x.hdf5`)."""
    from simreel.formats.registry import HDF5_SUFFIXES

    file = Path(file)
    return [other for other in sorted(file.parent.glob(glob.escape(file.stem) + ".*"))
            if other.stem == file.stem and other.suffix.lower() in HDF5_SUFFIXES and other.is_file()]


def obs_is_array(meta: RecordingMeta) -> bool:
    """Whether the recording's observation is one array (its only obs key is the obs mode's name)."""
    return list(meta.obs_layout) == [meta.obs_mode]


def dataset_name(field: str, meta: RecordingMeta) -> str:
    """Where field `field` is stored in a ``traj_N`` group."""
    if obs_is_array(meta) and field == f"{OBS}/{meta.obs_mode}":
        return OBS
    return field


def field_name(dataset: str, obs_mode: str) -> str:
    """The field a dataset of a ``traj_N`` group holds (inverse of `dataset_name`)."""
    return f"{OBS}/{obs_mode}" if dataset == OBS else dataset


def maniskill_tools(meta: RecordingMeta, *, hdf5: bool) -> list[str]:
    """What ManiSkill's own tools can do with a recording of `meta` (one line each), and why not where not."""
    if not hdf5:
        return ["ManiSkill's tools read HDF5 only: `simreel convert FILE.mcap FILE.h5` writes one they read"]
    lines = ["mani_skill.trajectory.replay_trajectory replays it (it needs a Vulkan device: see docs/setup.md)"]
    if meta.obs_layout:
        lines.append("ManiSkillTrajectoryDataset loads it with its observations (ManiSkill's layout)")
    else:
        lines.append("ManiSkillTrajectoryDataset loads it without observations, like ManiSkill's obs_mode=none "
                     "demos (record with --record-obs, or re-render them, to train on them)")
    return lines
