"""The options that choose how a replay is judged, declared once for every command that takes them: ``--mode`` (whose
default tolerances apply), ``--atol X`` and ``--tol GROUP=X`` (`simreel.options.declare`), with the parsing of their
values by the rule every tolerance keeps (`simreel.model.components.tolerance`)."""

from __future__ import annotations

import argparse

from simreel.model.components import GROUPS, TOLERANCE_MODES, tolerance
from simreel.options.declare import Option

__all__ = ["ATOL", "TOL", "TOLERANCE_GROUPS", "mode_choices", "parse_tolerance", "parse_group_tolerance"]

TOLERANCE_GROUPS = tuple(g for g in GROUPS if g != "flag")
"""The groups ``--tol`` takes: flags are always compared exactly."""


def parse_tolerance(text: str) -> float:
    """`--atol X`: a finite number >= 0."""
    return _tolerance_option(text, "")


def _tolerance_option(text: str, what: str) -> float:
    """`text` as a tolerance option's number, by the rule every tolerance keeps (`simreel.model.components.tolerance`)."""
    try:
        return tolerance(text, what)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e).lstrip()) from None


def parse_group_tolerance(text: str, groups: list[str] | tuple[str, ...] | None = None) -> tuple[str, float]:
    """`--tol GROUP=X`: `"contact=5"` → ("contact", 5.0), GROUP one of `groups` (default: `simreel.model.components.GROUPS`
    but "flag")."""
    groups = list(groups) if groups is not None else list(TOLERANCE_GROUPS)
    group, sep, value = text.partition("=")
    if not sep or group not in groups:
        raise argparse.ArgumentTypeError(f"expected GROUP=NUMBER with GROUP one of {', '.join(groups)}, got {text!r}")
    return group, _tolerance_option(value, f"{text!r}:")


def mode_choices() -> list[str]:
    """What `--mode` takes wherever it chooses tolerances: the replay modes (resync is `--mode actions --resync K`)."""
    return [m for m in TOLERANCE_MODES if m != "resync"]


ATOL = Option(help="one absolute tolerance for every compared value (flags stay exact)", flags=("--atol",), metavar="X",
              parse=parse_tolerance)
TOL = Option(help=f"tolerance of one group, repeatable; groups: {', '.join(TOLERANCE_GROUPS)}", flags=("--tol",),
             metavar="GROUP=X", parse=parse_group_tolerance, action="append", cli_default=[], from_cli=dict)
