"""Dataset operations: `merge` recordings of one env into one file, `filter_recording` (and split) a recording's
episodes by index, final success, length or a replay's verdicts.

Both are lossless and proven. Episodes are copied one at a time, a block of rows at a time (memory bounded
whatever an episode's length), through `simreel.datasets.copy`'s writer loop (a failure or Ctrl-C removes every
output); the outputs are then read back, a block at a time too, and every episode is checked against what was
read from its source: each array's name, dtype, shape and bytes, and the episode's metadata (BLAKE2b-256
digests of both, taken as the source was read: `HashedRows`). A difference is simreel's bug:
`OutputCheckError`, and the outputs are removed.

Inputs may be simreel HDF5 or MCAP recordings or ManiSkill trajectory files, mixed; the output's suffix picks
its format. Output episodes are numbered 0..N-1 in input order (as ManiSkill's `merge_trajectory` and
`clean_trajectories` number them), each with its `EpisodeMeta.origin` (input file and index there); the output's
`RecordingMeta.provenance` names the operation, each input (path, size, mtime, a digest of its metadata, its own
versions, command and provenance) and the criteria. What may differ between merged inputs, and why, is
`simreel.datasets.same_env`'s rule.
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import groupby
from pathlib import Path
from typing import Any

from simreel import FORMAT_VERSION
from simreel.datasets.copy import write_episodes
from simreel.datasets.digests import HashedRows, canonical_json, episode_digest
from simreel.datasets.inputs import file_identity, shown_path
from simreel.datasets.options import (
    DatasetOptions,
    EpisodeCriteria,
    no_success_note,
    uncovered_note,
)
from simreel.datasets.same_env import PHYSICS_NEUTRAL_ENV_KWARGS, PHYSICS_NEUTRAL_VERSIONS, check_same_env
from simreel.datasets.staged import StagedOutput, Target, clear_stale, publish_outputs
from simreel.errors import OutputCheckError, RecordingFileError, StorageError, UsageError
from simreel.formats import check_writable, format_of, open_reader, recording_files, remove_recording
from simreel.formats.base import not_a_file
from simreel.io.durable import raise_if_stopped
from simreel.io.paths import file_key, real_path, refuse_empty
from simreel.io.targets import check_distinct
from simreel.model.episode import Episode
from simreel.model.lineage import EpisodeOrigin
from simreel.model.meta import EpisodeMeta, RecordingMeta, new_recording_id
from simreel.options.checks import (
    options_with,
    path_list,
    path_text,
)
from simreel.verdicts.report_file import VERIFIED
from simreel.verdicts.scene_history import SceneChains

__all__ = ["DatasetOptions", "EpisodeCriteria", "DatasetReport", "OutputSummary", "merge", "filter_recording",
           "VERIFIED", "DIVERGED", "report_verdicts"]

DIVERGED = ("diverged",)
"""The verdict `filter --diverged` keeps (an episode that could not be replayed, ``error``, is neither)."""


@dataclass
class OutputSummary:
    """One file an operation wrote."""

    path: Path
    episodes: int
    steps: int
    cleared: list[Path] = field(default_factory=list)
    """What killed commands had left beside it under a staging name, removed once it was published."""

    def line(self) -> str:
        size = self.path.stat().st_size if self.path.exists() else 0
        return f"{self.episodes} episode(s), {self.steps} steps → {self.path} ({size / 1024:.0f} KiB)"


@dataclass
class DatasetReport:
    """What `merge` or `filter_recording` did."""

    operation: str
    outputs: list[OutputSummary]
    """OUT, then (a split) the rest."""
    inputs: list[tuple[Path, int, int]]
    """Each input, how many episodes it holds, and how many of them went to OUT."""
    checked: int
    """Episodes read back from the outputs and found equal to their sources."""
    no_success: int = 0
    """Episodes whose file holds no final success (with a success criterion: neither kept nor meeting it)."""
    uncovered: int = 0
    """Episodes a verdict criterion's replay report does not cover (not kept)."""
    criteria: str = ""
    """`EpisodeCriteria.describe` of a filter."""
    unfinished: list[str] = field(default_factory=list)
    """``<input>: <episode>`` for each episode an input holds uncommitted (a killed recording): not copied."""
    notes: list[str] = field(default_factory=list)
    """What else the output does not take from its inputs as they are (a render_mode they differ in)."""

    def summary(self) -> str:
        """What was written, from where, and what was checked: the text the CLI prints."""
        out = self.outputs[0]
        if self.operation == "merge":
            lines = [f"merged {len(self.inputs)} file(s): {out.line()}"]
            first = 0
            for path, _, n in self.inputs:
                span = f"episodes {first}-{first + n - 1}" if n > 1 else (f"episode {first}" if n else "nothing")
                lines.append(f"  {path.name:<24} {n:>6} episode(s) → {span}")
                first += n
        else:
            path, total, _ = self.inputs[0]
            lines = [f"filter {path.name} ({self.criteria}): kept {out.episodes} of {total}, {out.line()}"]
            lines += [f"rest: {o.line()}" for o in self.outputs[1:]]
        lines += [f"note: {u} was never committed (a killed recording) and is not copied" for u in self.unfinished]
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"note: removed {shown_path(p)}: the unchecked output of a merge or filter of {o.path.name} killed "
                  "before it finished" for o in self.outputs for p in o.cleared]
        lines += [f"note: {no_success_note(self.no_success)}"] if self.no_success else []
        lines += [f"note: {uncovered_note(self.uncovered)}"] if self.uncovered else []
        lines.append(f"checked: {self.checked} episodes, every array equal to its source")
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------- sources
@dataclass
class _Source:
    """One input as planned: its episode list and what identifies the file."""

    path: Path
    """Absolute."""
    label: str
    """As given on the command line."""
    meta: RecordingMeta
    episodes: list[EpisodeMeta]
    identity: dict[str, Any] = field(default_factory=dict)
    unfinished: list[str] = field(default_factory=list)
    """Episodes the file holds that were never committed (a killed recording): not listed, not copied."""
    notes: list[str] = field(default_factory=list)
    """What its reader says of the file as a whole (`EpisodeReader.notes`): groups of a ManiSkill file its sidecar
    does not list, which are not copied either, a sidecar that disagrees with its .h5."""
    chains: SceneChains | None = None
    """Its episodes' scene chains (`simreel.verdicts.scene_history`), for each copy to keep where it ran."""

    @classmethod
    def read(cls, path: str | Path) -> _Source:
        with open_reader(path) as reader:
            if reader.damaged:  # never left out silently: the output would lack them without a word
                raise RecordingFileError(path, f"{len(reader.damaged)} damaged episode(s) ({'; '.join(reader.damaged)})"
                                               f"; `simreel recover {path} -o OUT` copies the intact ones")
            source = cls(real_path(path), str(path), reader.meta, list(reader.episodes))
            size, mtime_ns = file_identity(path)
            m = reader.meta
            source.identity = {
                "path": str(source.path), "size": size, "mtime_ns": mtime_ns,
                "meta_digest": hashlib.blake2b(canonical_json(m.to_json()), digest_size=16).hexdigest(),
                "kind": reader.kind, "episodes": len(reader.episodes), "versions": m.versions,
                "created_utc": m.created_utc, "command": m.command, "source": m.source, "provenance": m.provenance,
            }
            source.unfinished = list(getattr(reader, "unfinished", []))
            source.notes = list(reader.notes)
            source.chains = SceneChains(source.episodes)
        return source

    def reopen(self) -> Any:
        """The input's reader again; `RecordingFileError` when the file changed since it was planned."""
        reader = open_reader(self.path)
        if file_identity(self.path) != (self.identity["size"], self.identity["mtime_ns"]):
            reader.close()
            raise RecordingFileError(self.label, "changed while it was being copied (size or mtime differ from when "
                                                "it was first read); run the command again")
        return reader


# ---------------------------------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class _Item:
    """One episode to copy: from which source, its index there, to which output, its index there."""

    source: int
    index: int
    target: int
    new_index: int


Decide = Callable[[_Source, EpisodeMeta], "int | None"]
"""Which output an episode goes to (its number in the target list), or None: not copied."""


@dataclass(frozen=True)
class _Selection:
    """Which episodes an operation copies where, as `_run` needs it."""

    decide: Decide
    what: str
    """The operation, for its progress bar: ``merge``, ``filter``."""
    why_none: Callable[[], str]
    """Why no episode goes to OUT, when none does (the error says it)."""


def _plan(sources: Sequence[_Source], decide: Decide, n_targets: int) -> list[_Item]:
    counts = [0] * n_targets
    items = []
    for k, source in enumerate(sources):
        for m in source.episodes:
            target = decide(source, m)
            if target is not None:
                items.append(_Item(k, m.index, target, counts[target]))
                counts[target] += 1
    return items


def _origin(source: _Source, meta: EpisodeMeta) -> EpisodeOrigin:
    """`EpisodeMeta.origin` of a copy of `meta`: where it was copied from, and where it ran when it was recorded
    (``scene``, for a replay to find its history: `simreel.verdicts.scene_history`)."""
    chains = source.chains
    scene = chains.copied_scene(meta.index, str(source.path), source.meta.recording_id) if chains is not None else None
    return EpisodeOrigin(str(source.path), meta.index, scene, meta.origin)


def _read(items: Sequence[_Item], sources: Sequence[_Source], decide: Decide,
          digests: list[list[bytes]]) -> Iterator[tuple[int, HashedRows]]:
    """Each item's episode, renumbered with its origin, to be read a block at a time, source by source (one
    reader open at a time); once it has been read, its digest goes to `digests[target]`. The decision is made
    again on the episode as opened: readers list each episode as it opens (a ManiSkill file's length is its
    actions' count from the start, not its sidecar's word), so a different one is simreel's bug (exit 3), never a
    silent change of the selection."""
    for k, group in groupby(items, key=lambda item: item.source):
        source = sources[k]
        with source.reopen() as reader:
            for item in group:
                raise_if_stopped()  # a Ctrl-C that landed in a finalizer (h5py's) was printed and dropped by Python
                rows = reader.open_episode(item.index)
                if decide(source, rows.meta) != item.target:
                    listed = _episode_meta(source, item.index)
                    raise RuntimeError(f"{source.label}: episode {item.index} opens as {rows.length} steps, success "
                                       f"{rows.meta.success}, but was listed, and selected, as {listed.length} "
                                       f"steps, success {listed.success}")
                meta = dataclasses.replace(rows.meta, index=item.new_index, origin=_origin(source, rows.meta))
                hashed = HashedRows(rows, meta)
                yield item.target, hashed
                digests[item.target].append(hashed.digest())


# ---------------------------------------------------------------------------------------------------- outputs
def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _common(dicts: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The entries every dict of `dicts` holds with the same value."""
    return {k: v for k, v in dicts[0].items() if all(k in d and d[k] == v for d in dicts[1:])}


def _versions(sources: Sequence[_Source]) -> dict[str, str]:
    """The inputs' versions (equal by the same-env rule but for simreel's own: its distinct values, joined)."""
    versions = dict(sources[0].meta.versions)
    for key in PHYSICS_NEUTRAL_VERSIONS:
        seen = list(dict.fromkeys(s.meta.versions[key] for s in sources if key in s.meta.versions))
        if seen:
            versions[key] = ", ".join(seen)
    return versions


def _env_kwargs(sources: Sequence[_Source]) -> dict[str, Any]:
    """The inputs' gym.make arguments (equal by the same-env rule but for `PHYSICS_NEUTRAL_ENV_KWARGS`): those
    kept where every input gives the same value, and left out where they differ (gym.make's default: no
    ``render_mode``, which needs no render device), since no one value is every episode's (`_neutral_differences`
    says so)."""
    shared = _common([s.meta.env_kwargs for s in sources])
    return {k: v for k, v in sources[0].meta.env_kwargs.items() if k not in PHYSICS_NEUTRAL_ENV_KWARGS or k in shared}


def _neutral_differences(sources: Sequence[_Source]) -> list[str]:
    """A note for each `PHYSICS_NEUTRAL_ENV_KWARGS` entry the inputs give different values, left out of the output."""
    notes = []
    for key in PHYSICS_NEUTRAL_ENV_KWARGS:
        labels: dict[str, list[str]] = {}
        for s in sources:
            value = s.meta.env_kwargs.get(key)
            labels.setdefault("none" if value is None else repr(value), []).append(s.label)
        if len(labels) > 1:
            given = "; ".join(f"{value} in {_some(names)}" for value, names in labels.items())
            notes.append(f"{key} differs between the inputs ({given}); it changes neither the physics nor the "
                         "arrays, and the output records none")
    return notes


def _some(labels: list[str]) -> str:
    return ", ".join(labels[:3]) + (f" and {len(labels) - 3} more" if len(labels) > 3 else "")


def _output_meta(sources: Sequence[_Source], provenance: dict[str, Any], command: str) -> RecordingMeta:
    return dataclasses.replace(
        sources[0].meta, created_utc=_now(), command=command, recording_id=new_recording_id(),
        format_version=FORMAT_VERSION,
        source=_common([s.meta.source for s in sources]), versions=_versions(sources), env_kwargs=_env_kwargs(sources),
        provenance={**provenance, "inputs": [s.identity for s in sources]},
    )


def _check_outputs(outputs: Sequence[str | Path], inputs: Sequence[str | Path], options: DatasetOptions) -> None:
    """The output rule, before any input is opened (only their names are needed): known suffixes, no output is an
    input (or a file beside one) or another output, none replaces a file without `overwrite`."""
    for path in outputs:
        format_of(path)
    files = {option: recording_files(p) for option, p in zip(("-o", "--rest"), outputs, strict=False)}
    for path in inputs:
        check_distinct(files, recording_files(path), input_label=f"input {path}")
    for path in outputs:
        check_writable(path, overwrite=options.overwrite)


def _run(sources: Sequence[_Source], targets: Sequence[Target], selection: _Selection,
         options: DatasetOptions) -> tuple[list[OutputSummary], list[_Item]]:
    """Plan, copy, check and publish: the work both operations share. The outputs are written under staging names
    (an old OUT stays until the new one is checked) and removed on any failure or Ctrl-C."""
    decide, what = selection.decide, selection.what
    items = _plan(sources, decide, len(targets))
    if not any(item.target == 0 for item in items):
        raise UsageError(f"no episode to write to {targets[0].path}: nothing matches ({selection.why_none()}); "
                         "nothing written")
    outputs = [StagedOutput.of(t) for t in targets]
    for item in items:
        outputs[item.target].items.append(item)
    try:
        episodes = _read(options.progress(items, what), sources, decide, [o.digests for o in outputs])
        steps = write_episodes([o.staged for o in outputs], episodes)
        for output in outputs:
            _check(output, sources, options)
        publish_outputs(outputs)  # every output or none: OUT is not published when --rest can no longer be
    except BaseException as e:
        for output in outputs:
            remove_recording(output.staged.path)
        if isinstance(e, StorageError):
            out = next((o.final.path for o in outputs if Path(e.path) == o.staged.path), e.path)
            raise e.dropped("; nothing was written and the inputs are unchanged", out) from None
        raise
    return [OutputSummary(o.final.path, len(o.items), n, clear_stale(o.final.path))
            for o, n in zip(outputs, steps, strict=True)], items


# ---------------------------------------------------------------------------------------------------- the check
def _check(output: StagedOutput, sources: Sequence[_Source], options: DatasetOptions) -> None:
    """Read the staged output back: its metadata as planned, episodes 0..N-1, each equal to its source (digests).
    Messages name the output by its final name."""
    name, digests = output.final.path, output.digests
    with open_reader(output.staged.path) as reader:
        if canonical_json(reader.meta.to_json()) != canonical_json(output.final.meta.to_json()):
            raise OutputCheckError(f"{name}: the recording metadata read back is not the one written")
        indices = [m.index for m in reader.episodes]
        if indices != list(range(len(digests))):
            raise OutputCheckError(f"{name}: holds episodes {indices[:10]}, expected 0..{len(digests) - 1}")
        for m in options.progress(reader.episodes, f"check {name.name}"):
            raise_if_stopped()
            if episode_digest(reader.open_episode(m.index)) != digests[m.index]:
                episode = reader.read_episode(m.index)
                raise OutputCheckError(f"{name}: episode {m.index} {_difference(episode, output.items[m.index], sources)}")


def _difference(got: Episode, item: _Item, sources: Sequence[_Source]) -> str:
    """What differs between an output episode and its source, read again, both whole (the rare path of a failed
    check)."""
    source = sources[item.source]
    with source.reopen() as reader:
        want = reader.read_episode(item.index)
    where = f"does not read back as episode {item.index} of {source.label}"
    ours = {k: v for k, v in got.meta.to_json().items() if k not in ("index", "origin")}
    theirs = {k: v for k, v in want.meta.to_json().items() if k not in ("index", "origin")}
    if ours != theirs:
        return f"{where}: its metadata differs"
    a, b = got.fields(), want.fields()
    for name in sorted(set(a) | set(b)):
        x, y = a.get(name), b.get(name)
        if x is None or y is None:
            return f"{where}: {name} is {'missing' if x is None else 'extra'}"
        if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
            return f"{where}: {name} is {x.dtype} {x.shape} here, {y.dtype} {y.shape} there, or its bytes differ"
    return f"{where} (its digest differs)"


# ---------------------------------------------------------------------------------------------------- operations
def _output_path(name: str, value: Any) -> str:
    """The output `value` (option `name`) as a str; `UsageError` for a value that is no path (a number would be taken
    for a file name, None fail as a raw TypeError) or an empty one."""
    path = path_text(name, value, "the recording to write, a str or pathlib.Path ending in .h5 or .mcap")
    refuse_empty(path, what="recording", instead=f"name the recording to write ({name})")
    return path


def _input_path(value: Any) -> str:
    """The input `value` of `filter_recording` as a str; `UsageError` for a value that is no path."""
    return path_text("path", value, "the recording to read, a str or pathlib.Path")


def merge(inputs: str | Path | Iterable[str | Path], output: str | Path, options: DatasetOptions | None = None,
          **overrides: Any) -> DatasetReport:
    """Copy every episode of `inputs` (recordings of one env, any format: a list of paths, or one) into a new
    recording `output`, numbered 0..N-1 in input order. `overrides` replace fields of `options` (`DatasetOptions`)."""
    opts = options_with(DatasetOptions, options, overrides, "merge(inputs, output, overwrite=True)")
    inputs = path_list("inputs", inputs, "the recordings to merge, a list of str or pathlib.Path (or one)")
    output = _output_path("output", output)
    if not inputs:
        raise UsageError("no input to merge")
    keys = [file_key(p) for p in inputs]  # a hard link, a symbolic link or another spelling of one file: the same
    twice = next((p for k, p in enumerate(inputs) if keys[k] in keys[:k]), None)
    if twice is not None:
        raise UsageError(f"{twice} is given twice; each input is merged once")
    _check_outputs([output], inputs, opts)
    sources = [_Source.read(p) for p in inputs]
    check_same_env([(s.label, s.meta) for s in sources])
    target = Target(Path(output), _output_meta(sources, {"operation": "merge"}, opts.command), opts.overwrite)
    everything = _Selection(lambda source, meta: 0, "merge", lambda: "the inputs hold no episode")
    outputs, items = _run(sources, [target], everything, opts)
    taken = [sum(1 for i in items if i.source == k) for k in range(len(sources))]
    return DatasetReport("merge", outputs, [(s.path, len(s.episodes), n) for s, n in zip(sources, taken, strict=True)],
                         outputs[0].episodes, unfinished=_unfinished(sources),
                         notes=[*_reader_notes(sources), *_neutral_differences(sources)])


def filter_recording(path: str | Path, output: str | Path, criteria: EpisodeCriteria,
                     options: DatasetOptions | None = None, *, rest: str | Path | None = None,
                     **overrides: Any) -> DatasetReport:
    """Copy the episodes of `path` that meet `criteria` into a new recording `output` (numbered 0..N-1), and with
    `rest` the others into a second one: a split, every episode in exactly one of them. `overrides` replace
    fields of `options` (`DatasetOptions`)."""
    opts = options_with(DatasetOptions, options, overrides, "filter_recording(path, output, criteria, overwrite=True)")
    if not isinstance(criteria, EpisodeCriteria):
        raise UsageError(f"criteria={criteria!r}: give an EpisodeCriteria, e.g. EpisodeCriteria(success=True)")
    path, output = _input_path(path), _output_path("output", output)
    rest = None if rest is None else _output_path("rest", rest)
    if not criteria.given():
        raise UsageError("no criterion: give --episodes, --success/--no-success, --min-steps, --max-steps, "
                         "--verified or --diverged (to copy every episode, use `simreel convert`)")
    outputs = [output] if rest is None else [output, rest]
    _check_outputs(outputs, [path], opts)
    source = _Source.read(path)
    held = {m.index for m in source.episodes}
    for index in criteria.episodes or ():  # one at a time: a range past the file's end stops at its first gap
        if index not in held:
            _episode_meta(source, index)  # raises, naming the episodes the file has
    provenance: dict[str, Any] = {"operation": "filter", "criteria": criteria.to_json()}
    parts = ["kept", "rest"][: len(outputs)]
    targets = [Target(Path(p), _output_meta([source], {**provenance, "part": part}, opts.command), opts.overwrite)
               for p, part in zip(outputs, parts, strict=True)]

    def decide(_: _Source, meta: EpisodeMeta) -> int | None:
        return 0 if criteria.keeps(meta) else (1 if rest is not None else None)

    written, _ = _run([source], targets, _Selection(decide, "filter", lambda: criteria.why_none(source.episodes)), opts)
    return DatasetReport(
        "filter", written, [(source.path, len(source.episodes), written[0].episodes)], sum(o.episodes for o in written),
        no_success=criteria.no_success(source.episodes), uncovered=criteria.uncovered(source.episodes),
        criteria=criteria.describe(), unfinished=_unfinished([source]), notes=_reader_notes([source]),
    )


def _reader_notes(sources: Sequence[_Source]) -> list[str]:
    """What the readers of `sources` said of each file, named by it, for the summary (as `inspect` and `replay` say
    it): a group a ManiSkill file's sidecar does not list is never left out without a word."""
    return [f"{s.label}: {note}" for s in sources for note in s.notes]


def _unfinished(sources: Sequence[_Source]) -> list[str]:
    return [f"{s.label}: {u}" for s in sources for u in s.unfinished]


def _episode_meta(source: _Source, index: int) -> EpisodeMeta:
    for m in source.episodes:
        if m.index == index:
            return m
    have = ", ".join(str(m.index) for m in source.episodes[:20]) or "none"
    raise RecordingFileError(source.label, f"no episode {index} (episodes: {have}{', ...' if len(source.episodes) > 20 else ''})")


def report_verdicts(path: str | Path, verdicts: Mapping[tuple[str, int], str],
                    files: Mapping[str, tuple[int | None, int | None]], report: str | Path) -> dict[int, str]:
    """The verdicts a replay report (`simreel.replay.read_verdicts`: (file, index) → verdict, and each file's
    (size, mtime_ns) when it was replayed) gives the episodes of `path`, by index.

    Raises `UsageError` when the report does not cover `path`, or when `path` changed since it was replayed (its
    size or mtime differ): its verdicts would be about another file."""
    p = Path(path)
    if not p.is_file():
        raise not_a_file(p)
    entry = next((f for f in files if real_path(f) == real_path(p)), None)
    if entry is None:
        raise UsageError(f"{report} holds no verdict for {path}: replay it with --report first (simreel replay "
                         f"{path} --report REPORT.json)")
    if tuple(files[entry]) != file_identity(p):
        raise UsageError(f"{path} changed since {report} verified it (its size or modification time differ): the "
                         "verdicts are about another file; replay it again")
    return {index: verdict for (f, index), verdict in verdicts.items() if f == entry}
