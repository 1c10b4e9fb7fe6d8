"""`ManiskillReader`: ManiSkill's own trajectory files (RecordEpisode, replay_trajectory, the published demos),
read onto simreel's episode model so that every command and the Python reader API work on them.

What such a file holds is mapped as it is; what it does not hold is listed in `RecordingMeta.unknown`, never
invented: simreel's versions, the full sim config and control frequency, contact forces, body poses, info
beyond success/fail, which resets rebuilt the scene, and — where the file lacks them — rewards, success,
fail and env_states. Quirks found in the file go to the episode's `EpisodeMeta.notes`:

- seeds stored as one-element lists in `reset_kwargs`, or a `reset_kwargs.seed` that is not the
  `episode_seed` (ManiSkill's replay_trajectory uses `episode_seed`, and so does simreel);
- `elapsed_steps` that is not the number of actions (or none: the length is the actions' count, noted when the
  reader is opened, so that every command selects and counts episodes by what they hold);
- a state row 0 equal to row 1 within restore noise: files that replay_trajectory wrote in its state modes
  (`--use-env-states`, `--use-first-env-state`) store the state *after* step 0 as the first state (off by
  one), so row 0 is not the reset state (`EpisodeMeta.initial_state_known` is False and replays skip it); a first
  step that moved nothing (an idle start) looks the same, and the note says both;
- episodes the sidecar lists that the .h5 lacks (an error), groups the sidecar does not list (skipped, as
  ManiSkill's tools skip them).

The first listed episode's datasets are the file's layout (its fields, and what the file is said to lack): an
episode holding other datasets, or some in another dtype or row shape, is refused when opened (an error naming it
and them), so that no array is left unchecked or uncopied while the rest of the episode passes. So is one holding
datasets none of ManiSkill's fields is (another tool's additions: `traj_N/my_extra`), by the rule of simreel's own
HDF5 files (`unlisted_datasets_problem`); the first episode's are named in `notes` when the file is opened, so that
`inspect` shows them.

Nothing in the sidecar is dropped unsaid either: keys the reader does not map are kept in `RecordingMeta.source`
(``other_sidecar_keys``: the top level's and ``env_info``'s, beside ``source_type``, ``source_desc``,
``commit_info``) or, for an episode entry's, quoted in a note on the episode, which every copy carries.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from simreel.errors import RecordingFileError
from simreel.formats.base import EpisodeReader, not_a_file
from simreel.formats.hdf5.reader import (
    H5PY_ERRORS,
    Hdf5Rows,
    datasets_below,
    open_hdf5,
    unlisted_datasets_problem,
)
from simreel.formats.maniskill.layout import OBS, dataset_name, field_name, group_index, group_name
from simreel.formats.maniskill.sidecar import Sidecar
from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances, component_error, components_of
from simreel.model.fields import OPTIONAL_STEP_FIELDS, episode_fields, field_group
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.model.state_tree import LeafSpec

__all__ = ["ManiskillReader", "ALWAYS_UNKNOWN"]

ALWAYS_UNKNOWN = ("versions", "sim_config", "control_freq", "contacts", "body_poses", "info", "scene_seeds")
"""What no ManiSkill trajectory file holds (besides the fields a given file lacks)."""
_DEFAULT_SIM_BACKEND = "physx_cpu"
"""ManiSkill's replay_trajectory assumes the CPU sim for files that do not name a backend."""
_UNLISTED_WHY = ("simreel reads ManiSkill's own datasets only, and refuses an episode holding others rather than drop "
                 "them: keep ManiSkill's tools for this file, or delete them from a copy (h5py: "
                 "del f['traj_N/<name>']) to use simreel on the rest")
"""Why a dataset of a ``traj_N`` group that no field reads is refused (`unlisted_datasets_problem`), and what to do."""
_EMPTY = ("the file holds no episodes: RecordEpisode writes one at each reset and at close, or with "
          "save_on_reset=False only at each flush_trajectory()")
"""The note on a file without ``traj_N`` groups beside a sidecar listing none: what RecordEpisode did not do."""
_ENTRY_KEYS = ("episode_id", "episode_seed", "control_mode", "elapsed_steps", "reset_kwargs", "success", "fail")
_RESET_KEYS = ("seed", "options")
"""An episode entry's keys, as ManiSkill 3.0.1 writes them, that the reader maps onto simreel's metadata (its
``fail`` is the last row of the ``fail`` data): any other key is quoted in a note on the episode
(`_note_sidecar_keys`), never dropped unsaid; the top level's and ``env_info``'s others are `Sidecar.other`."""
_NOTE_VALUE_CHARS = 200
"""The longest JSON of an episode entry's own key that its note quotes (a longer one is named, with its size)."""


def _layout(datasets: dict[str, Any]) -> dict[str, LeafSpec]:
    return {name: LeafSpec(tuple(ds.shape[1:]), ds.dtype.name) for name, ds in datasets.items()}


def _layout_differences(held: dict[str, LeafSpec], first: dict[str, LeafSpec]) -> list[str]:
    """How an episode's datasets (`held`, by `_layout`) differ from the first episode's (`first`): what it holds
    that the first lacks, what it lacks, and each dataset whose dtype or row shape differs (empty: none)."""
    extra, lacking = sorted(set(held) - set(first)), sorted(set(first) - set(held))
    out = [f"it holds {_names(extra)}, which the first lacks"] if extra else []
    out += [f"it lacks {_names(lacking)}"] if lacking else []
    return out + [f"its {name} is {held[name].dtype} {_rows(held[name])}, the first's {first[name].dtype} "
                  f"{_rows(first[name])}" for name in sorted(set(held) & set(first)) if held[name] != first[name]]


def _names(names: list[str]) -> str:
    return ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")


def _rows(spec: LeafSpec) -> str:
    return f"(T, {', '.join(str(n) for n in spec.shape)})" if spec.shape else "(T,)"


class ManiskillReader(EpisodeReader):
    """Reads a ManiSkill trajectory file (``traj_N`` groups + JSON sidecar). Raises `RecordingFileError` for a
    missing or mismatching sidecar, and for an HDF5 file that is no trajectory file at all."""

    def recover_hint(self) -> str:
        """`simreel recover` keeps the intact episodes of a ManiSkill file in a copy only (`-o`): in place it would
        replace it by a simreel recording."""
        copy = self.path.with_name(f"{self.path.stem}.recovered.h5")
        return f"`simreel recover {self.path} -o {copy}` copies its intact episodes (a ManiSkill file is recovered with -o)"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise not_a_file(self.path)
        self._file = open_hdf5(self.path)
        try:
            self._open()
        except BaseException:
            self._file.close()
            raise
        self.unfinished: list[str] = []

    def _open(self) -> None:
        groups = self._groups()
        self.sidecar = self._sidecar(groups)
        self.episodes = _episode_metas(self.sidecar, groups, self._action_rows)
        self.notes = _unlisted_groups(self.sidecar, groups) + ([] if groups else [_EMPTY])
        """Recording-level quirks (groups the sidecar does not list, a file without any)."""
        first = self._held(self.episodes[0].index) if self.episodes else None
        self._first = _layout(first) if first is not None else {}
        """The first listed episode's datasets (`_layout`): the file's layout, which every episode must have."""
        self.meta = _recording_meta(self.sidecar, first, self.episodes)
        _note_control_modes(self.sidecar, self.episodes, self.meta.control_mode)
        self.fields = episode_fields(self.meta)
        self._names = {f.name: dataset_name(f.name, self.meta) for f in self.fields}
        """Each field's dataset in a ``traj_N`` group: what the reader reads, and all an episode may hold."""
        unlisted = self._unlisted(self.episodes[0].index, first) if first is not None else None
        self.notes += [unlisted] if unlisted else []
        self.kind = f"ManiSkill trajectory file (JSON sidecar {self.sidecar.path.name})"

    def _groups(self) -> dict[int, str]:
        """The ``traj_N`` groups at the root by episode index (none: `_sidecar` tells an empty trajectory file from
        another HDF5 file); `RecordingFileError` where a ``traj_N`` is no group (not a trajectory file, or a damaged
        one)."""
        import h5py

        try:  # the object's kind from its header (h5o), without opening it: cheap for tens of thousands of groups
            found = {i: (name, h5py.h5o.get_info(self._file.id, name.encode()).type == h5py.h5o.TYPE_GROUP)
                     for name in self._file if (i := group_index(name)) is not None}
        except H5PY_ERRORS as e:
            raise RecordingFileError(self.path, f"corrupt HDF5 file: its list of groups cannot be read ({e})") from None
        odd = [name for name, is_group in found.values() if not is_group]
        if odd:
            raise RecordingFileError(self.path, f"{odd[0]} is a dataset, not a group of an episode's arrays: not a "
                                                "ManiSkill trajectory file, or a damaged one")
        return {i: name for i, (name, _) in found.items()}

    def _sidecar(self, groups: dict[int, str]) -> Sidecar:
        """The file's sidecar. A file without ``traj_N`` groups (`groups`) is a trajectory file only beside a sidecar
        that reads: one RecordEpisode wrote no episode into (`_EMPTY`; a sidecar listing some says the .h5 lacks
        them); without one, `RecordingFileError`: an HDF5 file of neither kind."""
        try:
            return Sidecar.read(self.path)
        except RecordingFileError:
            if groups:
                raise
            raise RecordingFileError(
                self.path, "an HDF5 file that is neither a simreel recording (no simreel metadata) nor a ManiSkill "
                "trajectory file (no traj_N groups)"
            ) from None

    def _held(self, index: int) -> dict[str, Any]:
        """Every dataset of episode `index`'s group (`datasets_below`); `RecordingFileError` when its structure cannot be
        read."""
        try:
            return datasets_below(self._file[group_name(index)])
        except H5PY_ERRORS as e:
            raise RecordingFileError(self.path, f"{group_name(index)} is corrupt: its structure cannot be read "
                                                f"({e})") from None

    def _action_rows(self, index: int) -> int | None:
        """How many actions episode `index` holds: the row count of its ``actions`` dataset, from the HDF5 metadata
        (no row is read: cheap for files of tens of thousands of episodes). None when it cannot be told (a group
        whose structure cannot be read, no ``actions``): `open_episode` names what is wrong with that episode, and
        the rest of the file stays readable."""
        import h5py

        try:
            return int(h5py.h5d.open(self._file.id, f"{group_name(index)}/actions".encode()).shape[0])
        except H5PY_ERRORS:
            return None

    def open_episode(self, index: int) -> Hdf5Rows:
        """Episode `index`: its datasets checked (`_episode_datasets`) and their row counts (T actions, T + 1 states),
        and the file's quirks noted in its metadata (`_note_quirks`: reads state rows 0 and 1 only)."""
        self.check_open()
        meta = dataclasses.replace(self.episode_meta(index))
        meta.notes = list(meta.notes)
        datasets = self._episode_datasets(index)
        steps = datasets["actions"].shape[0]
        for f in self.fields:
            rows = datasets[f.name].shape[0]
            if rows != f.row_count(steps):
                raise RecordingFileError(self.path, f"{group_name(index)}: episode {index}: {f.name} has {rows} rows, "
                                                    f"expected {f.row_count(steps)}")
        if meta.length != steps:  # listed from the same dataset's shape: only a file changed since it was opened
            raise RecordingFileError(self.path, f"{group_name(index)}: episode {index} holds {steps} actions, "
                                                f"{meta.length} when the file was opened: it changed meanwhile")
        _note_success(meta, datasets.get("success"))
        episode = Hdf5Rows(self.path, meta, self.fields, datasets)
        _note_quirks(episode)
        return episode

    def _episode_datasets(self, index: int) -> dict[str, Any]:
        """Episode `index`'s dataset of each field; `RecordingFileError` when its datasets differ from the first
        episode's (names, dtypes, row shapes): those are the file's layout, from which its fields and limits were
        made, so an episode that differs is refused, never read with arrays left out or unchecked."""
        held = self._held(index)
        differences = _layout_differences(_layout(held), self._first)
        if differences:
            first = group_name(self.episodes[0].index)
            raise RecordingFileError(self.path, f"{group_name(index)} differs from {first} (the first episode, whose "
                                                f"datasets set the file's layout): {'; '.join(differences)}")
        absent = [name for name in self._names.values() if name not in held]
        if absent:
            raise RecordingFileError(self.path, f"{group_name(index)} has no {_names(absent)}, which every episode of "
                                                "a ManiSkill trajectory file holds")
        unlisted = self._unlisted(index, held)
        if unlisted:
            raise RecordingFileError(self.path, unlisted)
        return {field: held[name] for field, name in self._names.items()}

    def _unlisted(self, index: int, held: dict[str, Any]) -> str | None:
        """What is wrong with episode `index` when its datasets (`held`) include some that no field reads (another
        tool's additions: `my_extra`, an extra group of observations): simreel's HDF5 rule
        (`unlisted_datasets_problem`), so that no copy drops them and no check passes them unchecked; None: none."""
        return unlisted_datasets_problem(group_name(index), held, self._names.values(), why=_UNLISTED_WHY)

    def close(self) -> None:
        self.closed = True
        self._file.close()


# --------------------------------------------------------------------------------------------- metadata
def _recording_meta(sidecar: Sidecar, held: dict[str, Any] | None, episodes: list[EpisodeMeta]) -> RecordingMeta:
    """The recording's metadata from the sidecar and the datasets its first episode holds (`held`; None: the
    sidecar lists no episode)."""
    from simreel.model.env_config import EnvConfig

    kw = sidecar.env_kwargs
    obs_mode = kw.get("obs_mode") or "state"
    found = held or {}
    states = field_group(found, "env_states")
    obs = {field_name(k, obs_mode)[len(OBS) + 1:]: ds for k, ds in found.items() if k == OBS or k.startswith(OBS + "/")}
    actions = found.get("actions")
    lacking = [name for name in OPTIONAL_STEP_FIELDS if held is not None and name not in held]
    num_envs = int(kw.get("num_envs") or 1)
    if num_envs > 1:  # RecordEpisode writes no reset options and no sub-scene index for parallel envs
        lacking += ["reset_options", "env_idx"]
    return RecordingMeta(
        env_id=sidecar.env_id,
        env_kwargs={k: v for k, v in kw.items() if k not in EnvConfig.names()},
        obs_mode=obs_mode,
        control_mode=kw.get("control_mode") or _episode_control_mode(sidecar),
        reward_mode=kw.get("reward_mode"),
        sim_backend=kw.get("sim_backend") or _DEFAULT_SIM_BACKEND,
        render_backend=kw.get("render_backend") or "none",
        num_envs=num_envs,
        max_episode_steps=sidecar.max_episode_steps,
        sim_config=dict(kw.get("sim_config") or {}),
        action_space={"shape": list(actions.shape[1:]), "dtype": actions.dtype.name} if actions is not None else {},
        state_layout=_layout(states),
        obs_layout=_layout(obs),
        command=str(sidecar.source.get("source_desc", "")),
        source={"format": "maniskill", **sidecar.source, "sidecar": str(sidecar.path),
                **({"other_sidecar_keys": sidecar.other} if sidecar.other else {})},
        unknown=[*ALWAYS_UNKNOWN, *lacking, *([] if states or held is None else ["env_states"])],
    )


def _note_sidecar_keys(entry: dict[str, Any], notes: list[str]) -> None:
    """A note quoting the keys of episode `entry` (and of its ``reset_kwargs``) that simreel's episode metadata has
    no field for, so that every copy of the episode carries them in its notes and no command calls it copied whole
    unsaid (a value longer than `_NOTE_VALUE_CHARS` of JSON is named with its size, not quoted)."""
    reset = entry.get("reset_kwargs") or {}
    other = {k: v for k, v in entry.items() if k not in _ENTRY_KEYS}
    other.update({f"reset_kwargs.{k}": v for k, v in reset.items() if k not in _RESET_KEYS})
    if not other:
        return
    quoted = []
    for key, value in other.items():
        text = json.dumps(value, default=str)
        quoted.append(f"{key}={text}" if len(text) <= _NOTE_VALUE_CHARS else
                      f"{key} ({len(text)} characters of JSON, not kept)")
    notes.append("its sidecar entry holds keys simreel's episode metadata has no field for, kept only in this note (a "
                 f"copy's sidecar lacks them): {', '.join(quoted)}")


def _note_control_modes(sidecar: Sidecar, episodes: list[EpisodeMeta], mode: str | None) -> None:
    """A note on each episode whose sidecar entry names another control mode than the recording's (`mode`, from the
    sidecar's env_kwargs, in which every episode is replayed): a sidecar that contradicts itself."""
    for meta, entry in zip(episodes, sidecar.episodes, strict=True):
        listed = entry.get("control_mode")
        if listed and mode and listed != mode:
            meta.notes.append(f"the sidecar lists this episode's control mode as {listed}, its env_kwargs as {mode}: "
                              f"replayed in {mode}")


def _episode_control_mode(sidecar: Sidecar) -> str | None:
    modes = {e.get("control_mode") for e in sidecar.episodes} - {None}
    return modes.pop() if len(modes) == 1 else None


def _unseeded_resets_are_random(sidecar: Sidecar) -> bool:
    """Whether an episode whose reset was given no seed was drawn from no seed at all: with one env (whose reset
    kwargs RecordEpisode records) and without ``enhanced_determinism``, ManiSkill 3.0.1 then initialises the episode
    from torch's global RNG, and RecordEpisode still writes the env's last seed as ``episode_seed``. With
    ``enhanced_determinism`` it draws a new episode seed and uses it: that ``episode_seed`` is the reset's."""
    kw = sidecar.env_kwargs
    return int(kw.get("num_envs") or 1) == 1 and not kw.get("enhanced_determinism")


def unseeded_reset(entry: dict[str, Any], *, unseeded_random: bool) -> bool:
    """Whether the episode of sidecar `entry` was reset without a seed, and such a reset is random
    (`_unseeded_resets_are_random`): its `episode_seed` is then likely stale, the env's last seed."""
    reset = entry.get("reset_kwargs") or {}
    return unseeded_random and bool(reset) and "seed" not in reset


def _seed(entry: dict[str, Any], notes: list[str], *, unseeded_random: bool) -> int | None:
    """The episode's seed: `episode_seed` (what replay_trajectory uses), checked against `reset_kwargs.seed`. Where
    the recorded reset kwargs hold no seed and such a reset is random (`unseeded_reset`), episode_seed is likely not
    its seed (``EpisodeMeta.seed_unchecked``): a replay checks it against the recorded first state."""
    seed = entry.get("episode_seed")
    reset = entry.get("reset_kwargs") or {}
    if unseeded_reset(entry, unseeded_random=unseeded_random):
        notes.append(f"reset without a seed (its reset_kwargs hold none): episode_seed {seed} may be stale "
                     "(ManiSkill draws an unseeded reset from torch's global RNG, and RecordEpisode writes the env's "
                     "last seed); an actions replay resets with it and checks it against env_states[0]")
        return int(seed) if isinstance(seed, (int, np.integer)) else None
    given = reset.get("seed")
    if isinstance(given, list):
        notes.append(f"reset_kwargs.seed is a list ({given}); ManiSkill's replay takes its one element")
        given = given[0] if len(given) == 1 else given
    if given is not None and seed is not None and given != seed:
        notes.append(f"reset_kwargs.seed {given} is not episode_seed {seed}; replayed with episode_seed")
    seed = seed if seed is not None else given
    return int(seed) if isinstance(seed, (int, np.integer)) else None


def _episode_metas(sidecar: Sidecar, groups: dict[int, str],
                   action_rows: Callable[[int], int | None]) -> list[EpisodeMeta]:
    """One `EpisodeMeta` per episode the sidecar lists, in its order, its length the actions its group holds
    (`action_rows` of its index: `_length`); an error for those the .h5 lacks, and for an episode listed twice (its
    group would be read twice, under the seeds of two entries)."""
    twice = [i for i, n in Counter(e["episode_id"] for e in sidecar.episodes).items() if n > 1]
    if twice:
        raise RecordingFileError(sidecar.path, f"lists {group_name(twice[0])} more than once: a sidecar lists each "
                                               "episode once")
    missing = [e["episode_id"] for e in sidecar.episodes if e["episode_id"] not in groups]
    if missing:
        shown = ", ".join(group_name(i) for i in missing[:5])
        raise RecordingFileError(sidecar.path, f"lists episodes the .h5 does not hold ({shown}): the sidecar belongs "
                                               "to another file, or the .h5 was cut")
    metas, unseeded_random = [], _unseeded_resets_are_random(sidecar)
    for entry in sidecar.episodes:
        notes: list[str] = []
        seed = _seed(entry, notes, unseeded_random=unseeded_random)
        _note_sidecar_keys(entry, notes)
        options = dict((entry.get("reset_kwargs") or {}).get("options") or {})
        metas.append(EpisodeMeta(
            index=entry["episode_id"],
            seed=seed,
            seed_unchecked=seed is not None and unseeded_reset(entry, unseeded_random=unseeded_random),
            reset_options=options,
            reconfigured=True if options.get("reconfigure") else None,
            length=_length(entry, action_rows(entry["episode_id"]), notes),
            success=entry.get("success") if isinstance(entry.get("success"), bool) else None,
            notes=notes,
        ))
    return metas


def _length(entry: dict[str, Any], actions: int | None, notes: list[str]) -> int:
    """An episode's length: the actions its group holds (`actions`), which filter, inspect, merge and replay go by,
    with a note where the sidecar's ``elapsed_steps`` says otherwise or nothing (a hand-edited or foreign sidecar).
    Where `actions` is None (its group cannot be read: opening it is an error), the sidecar's word, as listed."""
    listed = entry.get("elapsed_steps")
    if actions is None:
        return int(listed or 0)
    if listed is None:
        notes.append(f"the sidecar gives no elapsed_steps; {actions} actions in the file")
    elif listed != actions:
        notes.append(f"elapsed_steps {listed} in the sidecar, {actions} actions in the file")
    return actions


def _unlisted_groups(sidecar: Sidecar, groups: dict[int, str]) -> list[str]:
    listed = {e["episode_id"] for e in sidecar.episodes}
    extra = sorted(set(groups) - listed)
    if not extra:
        return []
    return [f"{len(extra)} group(s) the sidecar does not list ({', '.join(groups[i] for i in extra[:5])}) are "
            "skipped, as ManiSkill's tools skip them"]


def _note_success(meta: EpisodeMeta, success: Any) -> None:
    """A note where the sidecar's `success` (what inspect and filter go by, as ManiSkill's tools do) is not what the
    file's success data ends with (a hand-edited sidecar, or one of another file)."""
    if success is None or meta.success is None or not len(success):
        return
    last = bool(success[-1])
    if last != meta.success:
        meta.notes.append(f"the sidecar says success {meta.success}, the file's success data ends {last} (inspect and "
                          "filter --success go by the sidecar, as ManiSkill's tools do)")


def _note_quirks(episode: Hdf5Rows) -> None:
    """Notes on what the episode's first two state rows say about the file: an off-by-one row 0."""
    meta = episode.meta
    gap = _first_step_gap(episode.reset(), episode.steps(0, 1)) if episode.length >= 1 else None
    if gap is not None:
        meta.initial_state_known = False
        meta.notes.append(
            f"env_states[0] and env_states[1] agree within restore noise (largest difference {gap:.3g}): the first step "
            "moved nothing, or row 0 is the state after step 0 (off by one), as in files replay_trajectory writes with "
            "--use-env-states or --use-first-env-state; the reset state is not compared (--mode step checks a "
            "--use-env-states file as it was made: it restored the original's state at every step)"
        )


def _first_step_gap(reset: StepBlock, first: StepBlock) -> float | None:
    """The largest difference between state rows 0 (`reset`) and 1 (after the first step, `first`) when every part of
    every leaf agrees within the tolerances of a restore (`simreel.verdicts.compare`, mode ``states``), else None (a real first
    step moved something, or the file holds no states)."""
    states = [name for name in reset.arrays if name.startswith("env_states/")]
    if not states:
        return None
    tolerances, gap = Tolerances.for_mode("states"), 0.0
    for name in states:
        for comp in components_of(name.split("/", 1)[1], reset[name].shape[1:]):
            err = float(component_error(reset[name], first[name], comp)[0])
            if err > tolerances[comp.group]:
                return None
            gap = max(gap, err)
    return gap
