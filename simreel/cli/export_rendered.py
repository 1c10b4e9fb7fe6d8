"""`simreel export IN... --to lerobot OUT --obs-mode MODE`: observations the recordings lack (camera images of a
state-only recording) re-rendered from their recorded states, then exported. It composes two rooms, so it lives in
the CLI layer: each input's chosen episodes are converted first (`simreel.replay.convert.convert_recording`, as
`simreel convert IN X --obs-mode MODE` does: every state restored and checked, the observations rendered, only the
verified episodes written, the written file read back) into scratch recordings in OUT's scratch folder
(`ScratchFolder`: removed when the run ends, however it ends), and those are exported
(`simreel.training.lerobot.export.export_lerobot`). The dataset is written under a hidden name beside OUT and takes
its name only once its metadata names the inputs, not the scratch files: `meta/info.json`'s ``"simreel"`` lists the
inputs (path, identity, episodes), each with ``"rendered"``, the conversion that made its frames (the scratch
recording's provenance: modes, camera options, what was checked, the tolerances, the episodes left out and why), and
the episodes table names each episode's input file and the replay report's verdict.

Episodes a replay report leaves out are never converted (the report is checked against the inputs). Episodes whose
conversion check fails are left out of the dataset and named in the summary; the command then exits 1, as `simreel
convert` does (and writes nothing when none passes)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from simreel.cli.common import progress_bar
from simreel.datasets.inputs import file_identity, shown_path
from simreel.errors import SimreelError, UsageError
from simreel.formats import open_reader
from simreel.training.lerobot.options import ExportOptions

__all__ = ["RENDER_OPTIONS", "export_rendered", "render_options"]

RENDER_OPTIONS = ("obs_mode", "camera_size", "shader")
"""The `ConvertOptions` fields `simreel export` takes (declared once there)."""


def render_options(args: argparse.Namespace) -> Any:
    """The `ConvertOptions` of the re-rendering the export's command line asks for; None without --obs-mode."""
    from simreel.replay.convert.options import ConvertOptions

    given = {name: getattr(args, name) for name in RENDER_OPTIONS}
    if given["obs_mode"] is None:
        if any(v is not None for v in given.values()):
            raise UsageError("--camera-size and --shader apply to re-rendered observations: add --obs-mode")
        return None
    return ConvertOptions(**given, command=args.command_line)


def export_rendered(inputs: Sequence[str], out: str, options: ExportOptions, render: Any, *, quiet: bool) -> int:
    """Convert the chosen episodes of `inputs` with `render` (`ConvertOptions`), export the verified ones to `out`;
    prints the summary and returns the exit status (1 when an episode failed its conversion check)."""
    from simreel.replay.run.output import ScratchFolder
    from simreel.training.episodes import episode_count, select_episodes
    from simreel.training.lerobot.export import check_export_target

    target = check_export_target(out, overwrite=options.overwrite)  # before anything is converted
    chosen, files = select_episodes(inputs, report=options.report, keep=options.keep)
    by_file = {path: [e for e in chosen if e.path == path] for path in files}
    by_file = {path: refs for path, refs in by_file.items() if refs}
    for path in by_file:
        _refuse_rendered(path, files[path].meta, render)
    with ScratchFolder(target) as scratch:
        rendered = [_convert(path, [e.index for e in refs], scratch.path / f"{k:03d}.h5", render, quiet=quiet)
                    for k, (path, refs) in enumerate(by_file.items())]
        dropped = [(r.path, i, why) for r in rendered for i, why in sorted(r.dropped.items())]
        if not any(r.written for r in rendered):
            print(f"nothing exported: no episode passed its conversion check ({_named(dropped)})")
            return 1
        done = _Rendered(options, files, {(e.path, e.index): e.verdict for e in chosen}, rendered)
        summary = _export(done, target)
    left_by_report = episode_count(list(files)) - len(chosen) if options.report is not None else 0
    print(dataclasses.replace(summary, sources=list(by_file), left_out=left_by_report).summary())
    checked = rendered[0].conversion["checked"]
    print(f"re-rendered: {render.obs_mode} observations of {sum(len(r.written) for r in rendered)} episode(s) from "
          f"their recorded states; checked: {checked}"
          + (f"; {len(dropped)} left out by the conversion check: {_named(dropped)}" if dropped else ""))
    return 1 if dropped else 0


def _refuse_rendered(path: str, meta: Any, render: Any) -> None:
    """`UsageError` when `path` holds the observations asked for already: nothing to re-render."""
    if meta.obs_layout and meta.obs_mode == render.obs_mode and render.camera_size is None and render.shader is None:
        raise UsageError(f"{path} holds {meta.obs_mode} observations already (recorded with them): export it without "
                         "--obs-mode, or give --camera-size/--shader to render them anew")


def _convert(path: str, indices: list[int], scratch: Path, render: Any, *, quiet: bool) -> Any:
    from simreel.replay.convert.convert import convert_recording

    with progress_bar(quiet=quiet, total=len(indices), unit="ep", desc=f"render {Path(path).name}") as bar:
        return convert_recording(path, scratch, render, episodes=indices, keep=("verified",),
                                 progress=lambda ep: bar.update())


@dataclasses.dataclass
class _Rendered:
    """What the conversions made: the export's options, the inputs (path -> `SourceFile`), the report's verdict of
    each chosen episode ((path, index) -> verdict or None), and each input's `ConversionReport`."""

    options: ExportOptions
    files: dict[str, Any]
    verdicts: dict[tuple[str, int], Any]
    reports: list[Any]


def _export(done: _Rendered, target: Path) -> Any:
    """Export the scratch recordings into a staged folder, name the inputs in its metadata, then publish it."""
    from simreel.io.folders import staged_folder
    from simreel.training.lerobot.export import export_lerobot
    from simreel.training.lerobot.layout import is_lerobot_dataset

    options = done.options
    written = [r for r in done.reports if r.written]
    with staged_folder(target, overwrite=options.overwrite, looks_ours=is_lerobot_dataset,
                       kind="LeRobot dataset") as folder:
        plain = dataclasses.replace(options, report=None, overwrite=True)  # the staged folder is new and empty
        sys.stderr.flush()
        try:
            summary = export_lerobot([r.output for r in written], folder, plain)
        except SimreelError as e:  # about a scratch recording (a field it lacks): name the input it came from
            raise UsageError(_as_inputs(str(e), written)) from None
        _name_inputs(folder, done)
    return dataclasses.replace(summary, path=target)


def _name_inputs(folder: Path, done: _Rendered) -> None:
    """Make `folder`'s metadata name the inputs, not the scratch recordings: info.json's ``"simreel"`` sources (with
    the conversion that rendered each) and the episodes table's source file and verdict columns."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from simreel.training.lerobot.layout import EPISODES_PATH, INFO_PATH, chunk_file, write_json

    options, rendered = done.options, [r for r in done.reports if r.written]
    info = json.loads((folder / INFO_PATH).read_text())
    exported = {_key(s["path"]): s for s in info["simreel"]["sources"]}
    info["simreel"] = {**info["simreel"], "sources": [_source(r, exported[_key(r.output)], done.files[r.path]) for r in rendered],
                       "report": None if options.report is None else str(Path(options.report).resolve()),
                       "keep": list(options.keep) if options.report is not None else None,
                       "command": options.command}
    write_json(folder / INFO_PATH, info)
    path = folder / EPISODES_PATH.format(**chunk_file(0))
    table = pq.read_table(path)
    inputs = {_key(r.output): r.path for r in rendered}
    sources = [inputs[_key(p)] for p in table.column("simreel/source_file").to_pylist()]
    episodes = table.column("simreel/source_episode").to_pylist()
    for name, values in (("simreel/source_file", sources),
                         ("simreel/verdict", [done.verdicts[(p, i)] for p, i in zip(sources, episodes, strict=True)])):
        table = table.set_column(table.schema.get_field_index(name), pa.field(name, pa.string()),
                                 pa.array(values, pa.string()))
    pq.write_table(table, path)


def _source(report: Any, exported: dict[str, Any], source: Any) -> dict[str, Any]:
    """One input as info.json lists it: its identity and episodes, and the conversion that rendered its frames."""
    size, mtime_ns = file_identity(report.path)
    with open_reader(report.output) as reader:
        provenance = reader.meta.provenance
    rendered = {"obs_mode": provenance["conversion"]["obs_mode"][1], "conversion": provenance["conversion"],
                "tolerances": provenance["tolerances"], "written_check": report.written_check,
                "left_out": {str(i): why for i, why in sorted(report.dropped.items())}}
    return {**exported, "path": report.path, "size": size, "mtime_ns": mtime_ns,
            "recording_id": source.meta.recording_id, "obs_mode": source.meta.obs_mode, "rendered": rendered}


def _as_inputs(message: str, reports: Sequence[Any]) -> str:
    """`message` with each scratch recording's path replaced by that of the input it was rendered from."""
    for r in reports:
        for path in dict.fromkeys((_key(r.output), r.output)):
            message = message.replace(path, f"{r.path} (re-rendered)")
    return message


def _key(path: str) -> str:
    return str(Path(path).resolve())


def _named(dropped: Sequence[tuple[str, int, str]]) -> str:
    return ", ".join(f"{shown_path(p)} episode {i} ({why})" for p, i, why in dropped)
