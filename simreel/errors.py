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
    "EpisodeShapeError",
    "EpisodeLayoutError",
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

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        # the default rebuilds from `args` (the joined message), which this __init__ does not take; replay
        # workers send these errors back to the parent process pickled
        return type(self), (self.path, self.problem)


class RenderUnavailableError(SimreelError):
    """Something needs rendering (camera observations, video) but no render device exists."""


class EnvBuildError(SimreelError):
    """The env cannot be built: unknown env id, bad kwargs, a task module that fails to import."""


class ContactSpecError(SimreelError):
    """A contact pair names a body the scene does not have."""


class EpisodeShapeError(SimreelError):
    """An episode's arrays do not agree on its length (T rows per step, T+1 per state); names the field."""


class EpisodeLayoutError(EpisodeShapeError, ValueError):
    """An episode's arrays do not match the recording's layout: a field it lists is missing, or a row has
    another shape. Also a `ValueError`, which writers raised for this before."""

