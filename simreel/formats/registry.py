"""The reader/writer registry: a writer picked by file suffix, a reader by file content, and what each format keeps
beside a recording."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from simreel.errors import RecordingFileError, UsageError
from simreel.formats.base import EpisodeReader, EpisodeWriter
from simreel.formats.maniskill.layout import refuse_replacing_sidecar, sidecar_owners
from simreel.io.paths import read_head, refuse_empty
from simreel.io.replacement import INTERRUPTED, interrupted
from simreel.io.targets import check_output
from simreel.model.json_input import json_value
from simreel.model.meta import RecordingMeta
from simreel.options.checks import path_text

__all__ = ["open_writer", "check_writer_options", "open_reader", "format_of", "check_writable", "check_report_writable",
           "remove_recording", "recording_files", "records_poses_by_default", "writes_scene", "HDF5_SUFFIXES", "MCAP_SUFFIXES"]

HDF5_SUFFIXES = (".h5", ".hdf5")
MCAP_SUFFIXES = (".mcap",)


def format_of(path: str | Path) -> str:
    """"hdf5" or "mcap" from the file suffix; a clear error for anything else (an empty path, a folder named as
    such)."""
    refuse_empty(path, what="recording", instead="name a .h5 or .mcap file")
    suffix = Path(path).suffix.lower()
    if suffix in HDF5_SUFFIXES:
        return "hdf5"
    if suffix in MCAP_SUFFIXES:
        return "mcap"
    if Path(path).is_dir():
        raise UsageError(f"{path} is a folder, not a recording; name a .h5 (HDF5) or .mcap (MCAP) file")
    raise UsageError(f"{path}: unknown recording suffix {suffix!r}; use .h5 (HDF5) or .mcap (MCAP)")


def _writer_class(path: str | Path) -> type[EpisodeWriter]:
    """The writer of the format `path`'s suffix names."""
    if format_of(path) == "hdf5":
        from simreel.formats.hdf5.writer import Hdf5Writer

        return Hdf5Writer
    from simreel.formats.mcap.writer import McapWriter

    return McapWriter


def open_writer(path: str | Path, meta: RecordingMeta, **options: Any) -> EpisodeWriter:
    """A writer for `path`, chosen by its suffix (.h5/.hdf5 or .mcap); `options` are `overwrite` and the format's
    own (`check_writer_options`)."""
    path = path_text("path", path, "the recording to write, a str or pathlib.Path ending in .h5 or .mcap")
    check_writer_options(path, {k: v for k, v in options.items() if k != "overwrite"})
    return _writer_class(path)(path, meta, **options)


def check_writer_options(path: str | Path, options: Mapping[str, Any]) -> None:
    """`UsageError` for an option the writer of `path`'s format does not take (naming those it takes: HDF5's
    `compression`, MCAP's `simreel.formats.mcap.writer.McapOptions`), or a value it refuses; touches nothing, so a
    recorder checks its writer options before it starts anything."""
    writer = _writer_class(path)
    takes = writer.option_names()
    unknown = sorted(set(options) - set(takes))
    if unknown:
        raise UsageError(f"writer_options {', '.join(unknown)}: not an option of the {format_of(path).upper()} "
                         f"writer, which takes {', '.join(takes)}")
    writer.check_options(**options)


def check_writable(path: str | Path, *, overwrite: bool = False) -> None:
    """Raise the `UsageError` that `open_writer(path, ..., overwrite=overwrite)` would raise for the target
    itself (unknown suffix, missing folder, an existing file or side file without `overwrite`, an MCAP file
    another recording is writing), without creating anything: a command checks its output before slow work."""
    _writer_class(path).check_target(Path(path), overwrite=overwrite)


def check_report_writable(path: str | Path, *, overwrite: bool, option: str,
                          side_paths: Sequence[Path] = ()) -> Path:
    """Raise the `UsageError` that writing the report `path` of a command's `option` (``--report``, ``--json``: a
    file that is no recording), and the `side_paths` it writes beside it, would meet; touch nothing. Returns `path`.

    What `check_writable` refuses a recording, a report is refused by the same rule: a file a recording keeps beside
    it (an HDF5 file's JSON sidecar, which ManiSkill's tools read with it), `overwrite` or not
    (`simreel.formats.maniskill.layout.refuse_replacing_sidecar`); then what `simreel.io.targets.check_output`
    refuses. That `path` is none of the command's inputs the command checks first (`check_distinct`): it knows them."""
    for file in (Path(path), *side_paths):
        refuse_replacing_sidecar(file, writing=f"{option} {path}")
    return check_output(path, overwrite=overwrite, side_paths=side_paths, option=option)


def recording_files(path: str | Path) -> list[Path]:
    """The recording `path` and the files its format keeps beside it (HDF5: the JSON sidecar and the
    `.partial/` folder); just `path` for a suffix no format claims."""
    try:
        writer = _writer_class(path)
    except UsageError:
        return [Path(path)]
    return [Path(path), *writer.side_paths(Path(path))]


def remove_recording(path: str | Path) -> None:
    """Delete the recording `path` and the files its format keeps beside it (HDF5: the JSON sidecar and the
    `.partial/` scratch folder), e.g. a half-written output; missing ones are skipped."""
    _writer_class(path).remove(Path(path))


def records_poses_by_default(path: str | Path) -> bool:
    """Whether a recording to `path` should hold body poses unless told otherwise: True for MCAP (its `/tf`
    channel shows every link only with them), False for HDF5. Raises `UsageError` for an unknown suffix."""
    return _writer_class(path).records_poses_by_default


def writes_scene(path: str | Path) -> bool:
    """Whether a recording to `path` keeps what its scene looks like (`EpisodeWriter.write_scene`): True for MCAP,
    whose viewers have no other way to draw it. Raises `UsageError` for an unknown suffix."""
    return _writer_class(path).writes_scene


def open_reader(path: str | Path) -> EpisodeReader:
    """A reader for `path`, chosen by the file's magic bytes, whatever its suffix. `RecordingFileError` when a
    command replacing `path` was stopped between its renames (`simreel.io.replacement`)."""
    from simreel.formats.hdf5.layout import HDF5_MAGIC
    from simreel.formats.mcap.records import MCAP_MAGIC

    if not isinstance(path, (str, os.PathLike)):
        raise UsageError(f"{path!r}: give a recording's path, a str or Path")
    refuse_empty(path, what="recording", instead="name the recording to read")
    p = Path(path)
    if interrupted(p):  # before the file is looked for: a replacement of a new name may have moved its sidecar only
        raise RecordingFileError(p, f"{INTERRUPTED}; `simreel recover {p}` finishes that replacement")
    if not p.is_file():
        from simreel.formats.base import not_a_file

        raise not_a_file(p)
    head = read_head(p, 8)  # a file this user may not read: a RecordingFileError saying so
    if head == HDF5_MAGIC:
        from simreel.formats.hdf5.reader import Hdf5Reader, holds_simreel_metadata

        if holds_simreel_metadata(p):
            return Hdf5Reader(p)
        from simreel.formats.maniskill.reader import ManiskillReader

        return ManiskillReader(p)
    if head == MCAP_MAGIC:
        from simreel.formats.mcap.reader import McapReader

        return McapReader(p)
    if not head:
        raise RecordingFileError(p, "empty file")
    raise RecordingFileError(p, "neither an HDF5 nor an MCAP file" + _what_it_is(p, head))


_RRD_MAGIC = b"RRF2"
"""The first bytes of a Rerun session file (.rrd), which `simreel view --save` writes."""
_JSON_READ_LIMIT = 64 * 2**20
"""The largest JSON file read to say what it is: a replay report of very many episodes is a few tens of MiB."""


def _what_it_is(path: Path, head: bytes) -> str:
    """What a file that is no recording is, where simreel wrote it or reads it beside one, and what to give instead,
    as the end of the error that refuses it (empty where it is nothing simreel knows): a Rerun session, a replay
    report, a ManiSkill trajectory's JSON sidecar."""
    if head.startswith(_RRD_MAGIC):
        return f": a Rerun session (`simreel view --save` writes them); open it with `rerun {path}`"
    document = _json_document(path, head)
    if {"ok", "complete", "episodes", "files"} <= document.keys():
        judged = [f.get("path") for f in document.get("files") or () if isinstance(f, dict) and f.get("path")]
        wrote = f", and the replay it wrote: {document['output']}" if document.get("output") else ""
        return (f": a replay report (`simreel replay --report`); give a recording: the one it judged is "
                f"{', '.join(map(str, judged)) or 'not named in it'}{wrote}")
    if {"env_info", "episodes"} <= document.keys():
        owner = next(iter(sidecar_owners(path)), path.with_suffix(".h5"))
        return f": the JSON sidecar of a ManiSkill trajectory; give the .h5 beside it ({owner})"
    return ""


def _json_document(path: Path, head: bytes) -> dict[str, Any]:
    """The JSON object `path` holds, where it is one (of up to `_JSON_READ_LIMIT` bytes); else an empty dict."""
    if not head.lstrip().startswith(b"{") or path.stat().st_size > _JSON_READ_LIMIT:
        return {}
    try:
        document = json_value(path.read_bytes(), "it")
    except (OSError, ValueError):
        return {}
    return document if isinstance(document, dict) else {}
