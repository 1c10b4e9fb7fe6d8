"""Reading JSON that a file gives: a recording's metadata, a ManiSkill sidecar, an MCAP record, a replay report.
Whatever the file holds — text that is no JSON, bytes that are no UTF-8, arrays nested deeper than Python can
follow — comes out as one error naming the file, never as a raw Python error."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from simreel.errors import RecordingFileError

__all__ = ["parse_json", "json_value", "MAX_DEPTH"]

MAX_DEPTH = 100
"""The deepest nesting of arrays and objects read: far more than any file simreel or ManiSkill writes, and far
less than the depth at which Python's own recursion (copying, writing the value again) gives out."""
_TOO_DEEP = f"is nested more than {MAX_DEPTH} levels deep (deeper than any file simreel or ManiSkill writes)"


def parse_json(data: str | bytes, path: object, *, what: str = "its JSON",
               error: Callable[[Any, str], Exception] = RecordingFileError,
               then: str = "the file is damaged or not of this kind") -> Any:
    """`data` parsed as JSON; when it is not JSON, not UTF-8, or nested too deeply to read, `error(path, ...)`
    saying so of `what` (e.g. "its sidecar", "line 3"), followed by `then` (what that means, what to do; "":
    nothing)."""
    try:
        value = json.loads(data)
        if not _deeper_than(value, MAX_DEPTH):
            return value
        problem = _TOO_DEEP
    except RecursionError:
        problem = _TOO_DEEP
    except UnicodeDecodeError as e:
        problem = f"is not UTF-8 text (byte {e.start} cannot be decoded)"
    except json.JSONDecodeError as e:
        problem = f"is not JSON ({e.msg} at line {e.lineno} column {e.colno})"
    raise error(path, f"{what} {problem}" + (f": {then}" if then else "")) from None


def _deeper_than(value: Any, limit: int) -> bool:
    """Whether `value` nests arrays and objects more than `limit` levels deep (walked without recursion)."""
    stack = [(value, 1)] if isinstance(value, (dict, list)) else []
    while stack:
        item, depth = stack.pop()
        children = item.values() if isinstance(item, dict) else item
        if depth > limit:
            return True
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))
    return False


def _value_error(_: object, problem: str) -> ValueError:
    return ValueError(problem)


def json_value(data: str | bytes, what: str) -> Any:
    """`data` parsed as JSON, for a reader that names the file itself: ValueError saying what is wrong with `what`
    (`parse_json`)."""
    return parse_json(data, None, what=what, error=_value_error, then="")
