"""`ExportOptions`: what `simreel export --to lerobot` writes, each option declared once (`simreel.options.declare`):
the command's flags, their help and the Python checks come from these fields. Light to import: the CLI builds its
parser from it."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simreel.options.checks import flag, path_text, text, text_tuple
from simreel.options.declare import check_options, documented, option
from simreel.options.parallel import RAY, WORKERS, check_workers
from simreel.verdicts.report_file import REPORT_VERDICTS, VERIFIED

__all__ = ["ExportOptions", "FORMATS"]

FORMATS = ("lerobot",)
"""What `simreel export --to` writes."""


def _names(text: str) -> tuple[str, ...]:
    """``--state obs/agent/qpos,obs/extra``: the names, comma-separated."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"expected field names separated by commas, got {text!r}")
    return names


def _keep_text(text: str) -> tuple[str, ...]:
    """``--keep verified`` (exact and within_tolerance) or verdicts separated by commas."""
    wanted = tuple(w.strip() for w in text.split(",") if w.strip())
    wanted = tuple(v for w in wanted for v in (VERIFIED if w == "verified" else (w,)))
    unknown = [w for w in wanted if w not in REPORT_VERDICTS]
    if unknown or not wanted:
        raise argparse.ArgumentTypeError(f"expected verified or any of {', '.join(REPORT_VERDICTS)}, got {text!r}")
    return wanted


def _name_tuple(what: str) -> Any:
    return lambda name, value: text_tuple(name, value, what)


@documented
@dataclass(frozen=True)
class ExportOptions:
    """What `export_lerobot` writes and which episodes it takes."""

    state: tuple[str, ...] = option(
        (), metavar="FIELDS", parse=_names,
        help="fields joined into observation.state, comma-separated (names or groups: obs/agent/qpos, obs, "
             "env_states/articulations/panda); default: obs where the recording has observations (its camera "
             "frames go to videos), else env_states",
        check=_name_tuple("field names, e.g. ('obs/agent/qpos',), or () for the default"))
    extras: tuple[str, ...] = option(
        (), metavar="FIELDS", parse=_names,
        help="more fields as extra features: state fields as observation.environment_state, contact_forces as "
             "observation.contact_forces",
        check=_name_tuple("field names, e.g. ('env_states', 'contact_forces'), or ()"))
    task: str | None = option(None, metavar="TEXT", help="the task text of every episode (default: the env id)",
                              check=text("the task text as a string, or None (the env id)", optional=True))
    report: str | Path | None = option(
        None, metavar="REPORT.json", help="a `simreel replay --report` file: export only the episodes whose verdict "
                                          "--keep names (the verified ones by default)",
        check=lambda name, value: None if value is None else path_text(name, value, "the path of a replay report, "
                                                                                         "or None"))
    keep: tuple[str, ...] = option(
        VERIFIED, metavar="VERDICTS", parse=_keep_text,
        help="with --report: verified (exact, within_tolerance; the default) or verdicts separated by commas",
        check=_name_tuple(f"verdicts among {', '.join(REPORT_VERDICTS)}"))
    overwrite: bool = option(False, action="store_true", help="replace OUT if it is a LeRobot dataset",
                             check=flag())
    workers: int = option(1, spec=WORKERS)
    ray: str | None = option(None, spec=RAY)
    command: str = option("", cli=False, help="the command line, kept in meta/info.json",
                          check=text("the command line as a string"))

    def __post_init__(self) -> None:
        check_options(self)
        check_workers(self.workers)
