"""Upstream messages that tell a simreel user nothing to act on, kept out of their output: SAPIEN's warning that it
uses its bundled libvulkan (the system has none: expected, and it works), ManiSkill's that it falls back from the
``sapien_cuda`` render device on a machine without CUDA (simreel's own probe says what renders), and that
mani_skill was not installed from git.

`quiet_upstream_noise` hides exactly these (a warnings filter and a filter on ManiSkill's logger, matched by their
words); every other warning of SAPIEN or ManiSkill still shows. Importing `simreel.recorders.RecordWrapper`, or calling
`simreel.sim.make.prepare_plain_gym_make`, does it; set ``SIMREEL_SHOW_UPSTREAM_WARNINGS=1`` to see them again."""

from __future__ import annotations

import logging
import os
import re
import warnings

__all__ = ["quiet_upstream_noise", "SHOW_VARIABLE"]

SHOW_VARIABLE = "SIMREEL_SHOW_UPSTREAM_WARNINGS"
"""Set to 1: `quiet_upstream_noise` hides nothing."""

_WARNINGS = (r"Failed to find system libvulkan",)
"""Python warnings (UserWarning) hidden, by the start of their message."""

_LOG_LINES = re.compile(r'Requested to use render device "sapien_cuda", but CUDA device was not found'
                        r"|mani_skill is not installed with git")
"""ManiSkill log records hidden, by their message."""

_MANISKILL_LOGGER = "mani_skill "
"""The name ManiSkill 3.0.1 gives its logger (`mani_skill.utils.logging_utils`), trailing space included."""


class _KnownNoise(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return _LOG_LINES.search(record.getMessage()) is None


_FILTER = _KnownNoise()


def quiet_upstream_noise() -> None:
    """Hide the known upstream messages from now on (idempotent), unless `SHOW_VARIABLE` is set."""
    if os.environ.get(SHOW_VARIABLE, "").strip() not in ("", "0"):
        return
    for message in _WARNINGS:
        warnings.filterwarnings("ignore", message=message, category=UserWarning)
    logger = logging.getLogger(_MANISKILL_LOGGER)
    if _FILTER not in logger.filters:
        logger.addFilter(_FILTER)
