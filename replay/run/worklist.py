"""What a replay run over many recordings replays: the files its inputs name, and one work item per episode.

Inputs are recording files, folders of them and glob patterns (`simreel.datasets.inputs.expand_inputs`).
Each file's header is read once (metadata and episode list, no episode data); a file found by a folder or a
glob that is no recording is kept as unreadable (with the reason) rather than ending the run. The work items
are ordered by env key — the env a replay of the episode needs — so a worker that replays them in turn
rebuilds its env only when the key changes, then by file, then by episode index (recorded order, whatever order
``--episodes`` names them in): an actions replay first replays what ran in an episode's scene before it
(`simreel.verdicts.scene_history`), so episodes in recorded order replay no history twice.
"""

from __future__ import annotations

import dataclasses
import json
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simreel.datasets.inputs import expand_inputs, file_identity
from simreel.errors import FileProblemError, SimreelError, UsageError
from simreel.formats import open_reader
from simreel.model.meta import RecordingMeta, json_default
from simreel.model.selection import EpisodeSelection
from simreel.replay.report.report import only_flags_problem
from simreel.verdicts.scene_history import SceneChains

__all__ = ["RecordingInfo", "WorkItem", "WorkList", "env_key", "build_worklist", "chain_groups", "next_item"]

LACKING_LISTED = 20
"""How many of the episodes a file lacks a dataset run's warning names (`RecordingInfo.lacking`)."""


@dataclass(frozen=True)
class WorkItem:
    """One episode to replay: its env key, its file (absolute path), its index and its number of steps."""

    key: str
    path: str
    index: int
    steps: int = 0
    chain: str | None = None
    """In an actions replay, the scene chain of the recording it belongs to (`simreel.verdicts.scene_history`): the items
    of one chain are replayed by one process, in order, so no process replays another's episodes as history. None:
    any process, in any order (the other modes restore recorded states)."""


@dataclass
class RecordingInfo:
    """A file of the run: its header, or why it cannot be read."""

    path: str
    """Absolute path."""
    meta: RecordingMeta | None = None
    episodes: dict[int, int] = field(default_factory=dict)
    """Index → steps of each episode the run replays."""
    error: str | None = None
    """Why the file cannot be replayed (unreadable, foreign, no such episode); None when it can."""
    size: int | None = None
    mtime_ns: int | None = None
    """What identifies this version of the file: a resumed run refuses a file that changed."""
    lacking: list[int] = field(default_factory=list)
    """Episodes `--episodes` asks for that the file does not have (a dataset run replays the others): the first
    `LACKING_LISTED` + 1 at most (a range may name billions past the file's end)."""
    chains: dict[int, str] = field(default_factory=dict)
    """Index → its scene chain (`simreel.verdicts.scene_history.SceneChains.key`), for a run that replays actions."""

    @property
    def identity(self) -> tuple[int | None, int | None]:
        return self.size, self.mtime_ns


@dataclass
class WorkList:
    """The files of a run and its episodes, in the order they are replayed."""

    files: list[RecordingInfo]
    items: list[WorkItem]
    skipped: int = 0
    """Episodes not replayed because a resumed report already holds their verdict."""

    @property
    def readable(self) -> list[RecordingInfo]:
        return [f for f in self.files if f.error is None]


def env_key(meta: RecordingMeta) -> str:
    """What the env replaying an episode of `meta` depends on: two recordings with one key share an env."""
    from simreel.model.env_config import EnvConfig

    config = dataclasses.asdict(EnvConfig.from_meta(meta).with_overrides(num_envs=1))
    parts = [meta.env_id, config, meta.imports, [c.to_json() for c in meta.contact_channels], meta.pose_bodies,
             bool(meta.obs_layout), meta.obs_mode]
    return json.dumps(parts, sort_keys=True, default=json_default)


def _read_header(path: Path, wanted: EpisodeSelection | None, restores: str | None, *, some: bool,
                 chains: bool) -> RecordingInfo:
    """The header of the recording at `path`, with the episodes of `wanted` (None: all) it has; `some`: a file that
    lacks some of them replays the others (a dataset's files differ in length), else it is refused."""
    size, mtime_ns = file_identity(path) if path.is_file() else (None, None)
    with open_reader(path) as reader:
        if restores is not None and not reader.meta.state_layout:
            raise UsageError(f"{path}: holds no env_states (recorded without them), and {restores} restores recorded "
                             "states; replay it with --mode actions")
        only_flags = only_flags_problem(reader.meta)
        if only_flags:
            raise UsageError(f"{path}: {only_flags}")
        if wanted is None:
            reader.refuse_damaged("replayed")  # a damaged episode is never left out silently
        steps = {m.index: m.length for m in reader.episodes}
        lacking = [] if wanted is None else wanted.missing(steps, LACKING_LISTED + 1)
        if lacking and (not some or reader.damaged):  # a damaged episode is not listed: never take it for absent
            reader.episode_meta(lacking[0])  # raises RecordingFileError naming the episodes the file has
        if wanted is not None:
            steps = {i: steps[i] for i in wanted.pick(steps)}
        return RecordingInfo(str(path), reader.meta, steps, size=size, mtime_ns=mtime_ns, lacking=lacking,
                             chains=SceneChains(reader.episodes).key if chains else {})


def build_worklist(specs: Sequence[str | Path], *, episodes: EpisodeSelection | Sequence[int] | None = None,
                   done: Iterable[tuple[str, int]] = (), restores: str | None = None,
                   chains: bool = False) -> WorkList:
    """Read every input's header and list its episodes to replay (`episodes`: these indices of every file),
    ordered by env key, file and episode index, leaving out the (absolute path, index) pairs in `done` (a resumed
    run). `restores`: the option that makes the run restore recorded states (``--mode step``), so a file without any
    cannot be replayed. `chains`: the run replays actions, so each item names its scene chain (`WorkItem.chain`).

    A file given by name that cannot be read raises its `SimreelError`; one found in a folder or by a glob
    is kept with its error, so one bad file does not end a dataset run. A file of a dataset run (more than one
    file) that lacks some of the `episodes` replays those it has (`RecordingInfo.lacking` says which it lacks);
    the one file of a one-file run is refused.
    """
    files: list[RecordingInfo] = []
    wanted = EpisodeSelection.of(episodes)
    found = expand_inputs(specs)
    for path, explicit in found:
        try:
            files.append(_read_header(path, wanted, restores, some=len(found) > 1 or not explicit, chains=chains))
        except SimreelError as e:
            if explicit:
                raise
            files.append(RecordingInfo(str(path), error=str(e.problem if isinstance(e, FileProblemError) else e)))
    done_set = {(str(p), int(i)) for p, i in done}
    items: list[tuple[str, int, int, WorkItem]] = []
    skipped = 0
    for order, info in enumerate(files):
        if info.meta is None:
            continue
        key = env_key(info.meta)
        for index, steps in info.episodes.items():
            if (info.path, index) in done_set:
                skipped += 1
            else:
                chain = f"{info.path}{info.chains[index]}" if chains else None
                items.append((key, order, index, WorkItem(key, info.path, index, steps, chain)))
    items.sort(key=lambda x: x[:3])  # env key, then input order, then recorded order (`simreel.verdicts.scene_history`)
    return WorkList(files, [item for *_, item in items], skipped)


def chain_groups(items: Iterable[WorkItem]) -> list[list[WorkItem]]:
    """`items` in the runs one process replays in turn: the items of one chain (`WorkItem.chain`; a recording with
    parallel envs interleaves its sub-scenes' chains), in their order, where the chain's first item is; each item
    without a chain alone."""
    groups: dict[Any, list[WorkItem]] = {}
    for item in items:
        groups.setdefault(item.chain if item.chain is not None else object(), []).append(item)
    return list(groups.values())


def next_item(left: deque[WorkItem], groups: deque[list[WorkItem]]) -> WorkItem:
    """The next item for a process that holds `left` of its group (`chain_groups`): the group's next, or once the
    group is done, the first of the next group in `groups` (which the process then holds). A process finishes its
    group before it takes another, so a chain stays in one process."""
    if not left:
        left.extend(groups.popleft())
    return left.popleft()
