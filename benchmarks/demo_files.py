"""What the control-mode measurements (`measure_tracking.py`, `measure_control_modes.py`) share: their command line
(``--episodes``, ``--steps``) and pd_joint_pos demos recorded with ManiSkill's RecordEpisode as the tests record them
(`tests/support/maniskill_files.record_maniskill`)."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def demo_arguments(doc: str, *, episodes: int, steps: int) -> argparse.Namespace:
    """The measurement's arguments: demos per task or robot (`episodes`) of `steps` steps, as defaults."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--episodes", type=int, default=episodes)
    p.add_argument("--steps", type=int, default=steps)
    return p.parse_args()


def demo_recorder() -> Callable[..., Any]:
    """The tests' `record_maniskill`, ManiSkill's warnings silenced."""
    sys.path.insert(0, str(REPO / "tests"))
    warnings.filterwarnings("ignore")
    from support.maniskill_files import record_maniskill

    return record_maniskill
