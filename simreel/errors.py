"""The one exception hierarchy of simreel: every error it raises on purpose is defined here.

Every error a user can cause (bad file, bad option, unknown env) is a `SimreelError`; the CLI turns it
into one line on stderr and exit status 2. Messages name what was found, what was expected and the fix.
"""

from __future__ import annotations

__all__ = [
    "EPISODE_DATA_ERRORS",
    "SimreelError",
    "UsageError",
    "ActionError",
    "FileProblemError",
    "RecordingFileError",
    "ReportFileError",
    "StorageError",
    "Terminated",
    "RenderUnavailableError",
    "EnvBuildError",
    "ContactSpecError",
    "EpisodeLayoutError",
    "MetadataError",
    "KeyPathError",
    "StateLayoutError",
    "CustomStateError",
    "TaskCodeError",
    "HeterogeneousBuildError",
    "ReplayError",
    "ViewError",
    "EnvMismatchError",
    "OutputCheckError",
]


class SimreelError(Exception):
    """Base of every error simreel raises on purpose."""


class UsageError(SimreelError):
    """A bad option or argument value."""


class ActionError(UsageError):
    """An action a recorder cannot pass on: not an array, another shape than the action space's, NaN or infinity."""


class FileProblemError(SimreelError):
    """A file simreel reads is missing or unusable: `path` and the `problem`, joined as ``path: problem``."""

    def __init__(self, path: object, problem: str) -> None:
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        # the default rebuilds from `args` (the joined message), which this __init__ does not take; replay
        # workers send these errors back to the parent process pickled
        return type(self), (self.path, self.problem)


class RecordingFileError(FileProblemError):
    """A recording file is missing, truncated, foreign or of an unknown format version."""


class ReportFileError(FileProblemError):
    """A replay report (`--report`, `--resume`) is missing, damaged, of another run, or being written by another
    process."""


class StorageError(RecordingFileError):
    """The storage refused a write (a full disk, a read-only file system, no permission): bad input for the user to
    fix, never an internal error. `reason` says what happened, `fix` what to do."""

    def __init__(self, path: object, reason: str, fix: str, detail: str = "") -> None:
        self.reason = reason
        self.fix = fix
        self.detail = detail
        super().__init__(path, f"{reason}{detail}; {fix}")

    def __reduce__(self) -> tuple[type, tuple[str, str, str, str]]:
        return type(self), (self.path, self.reason, self.fix, self.detail)

    def dropped(self, detail: str, path: object = None) -> StorageError:
        """The same failure, said by a command that dropped what it was writing: `detail` (e.g. "; nothing was
        written") replaces what the writer said of the episodes it had committed; `path`, the output's name, the one
        the writer wrote under (a staging name)."""
        return StorageError(self.path if path is None else path, self.reason, self.fix, detail)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C's KeyboardInterrupt so that the same clean-up runs (the CLI installs it)."""


class RenderUnavailableError(SimreelError):
    """Something needs rendering (camera observations, video) but no render device exists."""


class EnvBuildError(SimreelError):
    """The env cannot be built: unknown env id, bad kwargs, a task module that fails to import."""


class ContactSpecError(SimreelError):
    """A contact pair names a body the scene does not have."""


class EpisodeLayoutError(SimreelError, ValueError):
    """An episode's arrays do not fit its recording's field table (`simreel.model.fields.episode_fields`): a field
    is missing, has another row shape, or a row count that does not fit T (per step) or T+1 (per state).
    Also a `ValueError`, which writers raised for this before."""


class MetadataError(SimreelError, ValueError):
    """Recording metadata (`RecordingMeta`, `EpisodeMeta`, a layout) read from JSON is malformed: a field is
    missing or of the wrong type. Readers report it with the file's name."""


EPISODE_DATA_ERRORS = (RecordingFileError, EpisodeLayoutError, MetadataError)
"""Errors about one episode's data (damaged, missing, malformed); any other error reading or replaying it is about
the env its file needs (it does not build, another state layout) and stops every episode of that file alike."""


class KeyPathError(SimreelError, ValueError):
    """A nested state dict cannot become flat key paths, or flat key paths cannot become a nested dict (a key
    holding ``/``, an empty key, a path below a leaf)."""


class StateLayoutError(SimreelError):
    """A live env's state dict does not have the layout (key paths, shapes, dtypes) a recording needs: the
    task changed its layout between episodes, or a rebuilt env differs from the recorded one."""


class CustomStateError(SimreelError):
    """A declared custom state attribute is missing, has the wrong shape, or a state dict lacks it."""


class TaskCodeError(SimreelError):
    """A task's own code (its `set_state_dict`, say) raised: a bug for the task's author, named with the call."""


class HeterogeneousBuildError(SimreelError):
    """Parts that cannot be merged into one record-safe heterogeneous view (DOF over the declared bound, a
    missing link); see `simreel.authoring.heterogeneous`."""


class ReplayError(SimreelError):
    """A recording cannot be replayed here: a bad mode, or a GPU recording on a machine without CUDA."""


class ViewError(SimreelError):
    """A recording cannot be shown: --compare does not fit it, or the Rerun viewer cannot start."""


class EnvMismatchError(SimreelError):
    """Recordings that would become one file (`simreel merge`) record different envs: the message names the first
    field that differs (`simreel.datasets.same_env`)."""


class OutputCheckError(RuntimeError):
    """A file simreel wrote does not read back as what it copied (`simreel merge`, `simreel filter`): a bug in
    simreel, never bad input, hence not a `SimreelError` (the CLI exits 3 and removes the file)."""
