"""Reading JSON that a file gives: a recording's metadata, a ManiSkill sidecar, a replay report. Whatever the file
holds — text that is no JSON, bytes that are no UTF-8, arrays nested deeper than Python can follow — comes out as
one `FileProblemError` naming the file, never as a raw Python error."""

from __future__ import annotations

import json
from typing import Any

from simreel.errors import FileProblemError, RecordingFileError

__all__ = ["parse_json"]


def parse_json(data: str | bytes, path: object, *, what: str = "its JSON",
               error: type[FileProblemError] = RecordingFileError,
               then: str = "the file is damaged or not of this kind") -> Any:
    """`data` parsed as JSON; when it is not JSON, not UTF-8, or nested too deeply to read, `error(path, ...)`
    saying so of `what` (e.g. "its sidecar", "line 3"), followed by `then` (what that means, what to do)."""
    try:
        return json.loads(data)
    except RecursionError:
        problem = "is nested too deeply to be read (deeper than any file simreel or ManiSkill writes)"
    except UnicodeDecodeError as e:
        problem = f"is not UTF-8 text (byte {e.start} cannot be decoded)"
    except json.JSONDecodeError as e:
        problem = f"is not JSON ({e.msg} at line {e.lineno} column {e.colno})"
    raise error(path, f"{what} {problem}: {then}") from None
