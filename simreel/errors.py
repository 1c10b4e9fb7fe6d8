"""The one exception hierarchy of simreel.

Every error a user can cause (bad file, bad option, unknown env) is a `SimreelError`; the CLI turns it
into one line on stderr and exit status 2. Messages name what was found, what was expected and the fix.
"""

from __future__ import annotations

__all__ = [
    "SimreelError",
    "UsageError",
    "RecordingFileError",
    "RenderUnavailableError",
    "EnvBuildError",
    "ContactSpecError",
]


class SimreelError(Exception):
    """Base of every error simreel raises on purpose."""


class UsageError(SimreelError):
    """A bad option or argument value."""


class RecordingFileError(SimreelError):
    """A recording file is missing, truncated, foreign or of an unknown format version."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


class RenderUnavailableError(SimreelError):
    """Something needs rendering (camera observations, video) but no render device exists."""


class EnvBuildError(SimreelError):
    """The env cannot be built: unknown env id, bad kwargs, a task module that fails to import."""


class ContactSpecError(SimreelError):
    """A contact pair names a body the scene does not have."""
