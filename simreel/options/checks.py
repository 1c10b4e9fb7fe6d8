"""Checks of the options the rooms take from Python (`RecordOptions` and `RecordWrapper`, `ReplayOptions` and
`ReplayRun`, `AuditOptions` and `audit_task`, `ReplayerOptions` and `EpisodeReplayer`, `DatasetOptions` and `merge`,
...): a value of the wrong type, or a keyword that is no option (`options_with`), is a `UsageError` that names the
option and says what to give, raised when the options are built, before anything starts. Unchecked, it fails later as a raw Python error, or is silently taken
for another value: ``overwrite="no"`` counts as yes, ``resync=1.5`` restores at fractional steps, ``True`` counts
as 1, a number is taken for a file name.

Each rule is here once; the message is always ``name=value: give what``, `what` saying what the option means.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import numbers
import os
from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

import numpy as np

from simreel.errors import UsageError

__all__ = ["check_flag", "check_text", "check_mapping", "check_callable", "text_tuple", "is_whole_number",
           "whole_number", "whole_number_pair", "is_path", "path_text", "path_list", "options_with", "parse_size", "parse_json_kwargs", "refuse_empty", "Check", "flag",
           "text", "mapping", "function", "whole", "path"]

Options = TypeVar("Options")


def _refused(name: str, value: Any, what: str) -> UsageError:
    return UsageError(f"{name}={value!r}: give {what}")


def check_flag(name: str, value: Any) -> None:
    """`UsageError` for a yes/no option that is not a bool: any truthy value would count as yes (``overwrite="no"``
    replacing a file)."""
    if not isinstance(value, (bool, np.bool_)):
        raise _refused(name, value, "True or False")


def check_text(name: str, value: Any, what: str, *, optional: bool = False) -> None:
    """`UsageError` saying to give `what` for an option that is not a string (or None, when `optional`): it would be
    passed on to where a string is expected (an env's mode, a Ray address) and fail there, or be stored where the
    file could not be read back."""
    if not isinstance(value, str) and not (optional and value is None):
        raise _refused(name, value, what)


def check_mapping(name: str, value: Any, what: str) -> None:
    """`UsageError` saying to give `what` for an option that is not a dict (or another mapping): a list would fail
    later as a raw TypeError where it is read as one (``dict(value)``, ``value.items()``)."""
    if not isinstance(value, Mapping):
        raise _refused(name, value, what)


def check_callable(name: str, value: Any, what: str) -> None:
    """`UsageError` saying to give `what` for an option that is neither a callable nor None: it would fail as a raw
    TypeError only when first called, after the work before it."""
    if value is not None and not callable(value):
        raise _refused(name, value, what)


def text_tuple(name: str, value: Any, what: str) -> tuple[str, ...]:
    """`value`, one string or an iterable of strings, as a tuple of strings; `UsageError` saying to give `what` for
    anything else. One string is one name: taken as an iterable it would be one name per character (``"x.py"`` as
    the modules x, ., p, y)."""
    names = (value,) if isinstance(value, str) else tuple(value) if isinstance(value, Iterable) else None
    if names is None or not all(isinstance(n, str) for n in names):
        raise _refused(name, value, what)
    return names


def is_whole_number(value: Any) -> bool:
    """Whether `value` is a whole number: an int or a numpy int, not a bool. A bool or a float would be taken for
    another count (True as 1, 1.5 where only whole steps exist), a string fail later as a raw TypeError."""
    return isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_))


def whole_number(name: str, value: Any, what: str, *, minimum: int | None = None) -> int:
    """`value` as an int; `UsageError` saying to give `what` unless it is a whole number (`is_whole_number`) of at
    least `minimum` (when given)."""
    if not is_whole_number(value) or (minimum is not None and value < minimum):
        raise _refused(name, value, what)
    return int(value)


def whole_number_pair(name: str, value: Any, what: str) -> tuple[int, int]:
    """`value`, a list or tuple of two whole numbers (a size: width, height), as a tuple of ints; `UsageError` saying
    to give `what` for anything else (text such as "128x128" is no pair: the CLI parses it)."""
    pair = tuple(value) if isinstance(value, (list, tuple)) else ()
    if len(pair) != 2 or not all(map(is_whole_number, pair)):
        raise _refused(name, value, what)
    return int(pair[0]), int(pair[1])


def parse_size(text: str) -> tuple[int, int]:
    """The command line's text of a size: `"256x128"` → (256, 128), an image's width and height (`--size`,
    `--camera-size`); argparse's error for anything else."""
    width, sep, height = text.lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit() or int(width) < 1 or int(height) < 1:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 256x256, got {text!r}")
    return int(width), int(height)


def parse_json_kwargs(text: str) -> dict[str, Any]:
    """`--env-kwargs`: a JSON object, strictly: Python's json also takes NaN and Infinity, which no JSON reader of the
    recording's metadata would (and a NaN sim setting fails inside ManiSkill)."""
    try:
        value = json.loads(text, parse_constant=_no_json_constant)
    except json.JSONDecodeError as e:
        raise argparse.ArgumentTypeError(f"not valid JSON ({e.msg})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("expected a JSON object")
    return value


def _no_json_constant(name: str) -> Any:
    raise argparse.ArgumentTypeError(f"not valid JSON ({name} is no JSON number; give a finite number)")


def is_path(value: Any) -> bool:
    """Whether `value` names a file: a str or an `os.PathLike` of one (`pathlib.Path`), not bytes nor a number."""
    return isinstance(value, str) or (isinstance(value, os.PathLike) and isinstance(os.fspath(value), str))


def path_text(name: str, value: Any, what: str) -> str:
    """`value`, a path (`is_path`), as a str; `UsageError` saying to give `what` for anything else: a number would be
    taken for a file name, or fail later as a raw TypeError."""
    if not is_path(value):
        raise _refused(name, value, what)
    return os.fspath(value)


def path_list(name: str, value: Any, what: str) -> list[str]:
    """`value`, one path (`is_path`) or an iterable of them (a list, a generator), as a list of strs; `UsageError`
    saying to give `what` for anything else. One path is one file, never iterated: ``"a.h5"`` read as a list would
    be the files ``a``, ``.``, ``h``, ``5``."""
    paths = [value] if is_path(value) else list(value) if isinstance(value, Iterable) else None
    if paths is None or not all(map(is_path, paths)):
        raise _refused(name, value, what)
    return [os.fspath(p) for p in paths]


def refuse_empty(path: str | os.PathLike, *, what: str, instead: str) -> None:
    """`UsageError` for an empty or blank `path`, which names no `what` (``recording``, ``folder``) though `Path("")`
    is the working folder: ``simreel replay "$UNSET"`` would read everything there, ``video -o "$UNSET"`` write into
    it. `instead` says what to give."""
    if not str(path).strip():
        raise UsageError(f"an empty path names no {what} (an unset shell variable?); {instead}")


def options_with(options_type: type[Options], options: Any, overrides: Mapping[str, Any], example: str) -> Options:
    """`options` (None: the defaults) with `overrides`, fields of `options_type` given as keywords, as a call that takes
    an options object or its fields (``ReplayRun(paths, mode="step")``) reads them; `UsageError` for options of
    another type (a dict would fail inside `dataclasses.replace`) or a keyword that is no option (Python's TypeError
    would name the options' ``__init__``, not the call, nor the options there are). `example`: such a call."""
    if options is not None and not isinstance(options, options_type):
        kind = options_type.__name__
        raise _refused("options", options, f"{'an' if kind[0] in 'AEIOU' else 'a'} {kind}, or its fields as keywords, "
                                           f"e.g. {example}")
    fields = [f.name for f in dataclasses.fields(options_type) if f.init]  # type: ignore[arg-type]
    for name, value in overrides.items():
        if name not in fields:
            raise _refused(name, value, f"only the options {options_type.__name__} has: {', '.join(fields)}")
    return dataclasses.replace(options or options_type(), **overrides)  # type: ignore[type-var]


# ------------------------------------------------------------------- the same rules as an option's declared check
Check = Callable[[str, Any], Any]
"""``check(name, value)``: the value in its one form, or `UsageError` naming `name` (`simreel.options.declare`)."""


def flag() -> Check:
    """A yes/no option (`check_flag`)."""
    return lambda name, value: check_flag(name, value) or value


def text(what: str, *, optional: bool = False) -> Check:
    """A string option (`check_text`)."""
    return lambda name, value: check_text(name, value, what, optional=optional) or value


def mapping(what: str) -> Check:
    """A dict option (`check_mapping`)."""
    return lambda name, value: check_mapping(name, value, what) or value


def function(what: str) -> Check:
    """A callable option, or None (`check_callable`)."""
    return lambda name, value: check_callable(name, value, what) or value


def whole(what: str, *, optional: bool = False) -> Check:
    """A count (`whole_number`), None too where `optional`."""
    return lambda name, value: None if optional and value is None else whole_number(name, value, what)


def path(what: str) -> Check:
    """A file to write, or None: a str (`path_text`), never empty (an unset shell variable would be taken for None)."""
    def checked(name: str, value: Any) -> str | None:
        if value is None:
            return None
        given = path_text(name, value, what)
        refuse_empty(given, what="file", instead=f"give {what}")
        return given

    return checked
