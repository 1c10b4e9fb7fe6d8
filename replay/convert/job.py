"""What every worker of one conversion is given (`ConvertJob`, picklable: worker processes build their own
workers) and what converting one episode gives back (`ConvertResult`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from simreel.model.components import Tolerances
from simreel.model.lineage import ScenePlace
from simreel.replay.run.job import EpisodeResult
from simreel.replay.run.output import ReplayOutput

if TYPE_CHECKING:
    from simreel.replay.convert.worker import ConvertWorker

__all__ = ["ConvertJob", "ConvertResult", "states_tolerances"]


@dataclass(frozen=True)
class ConvertJob:
    """What every worker of one conversion does (picklable: worker processes build their own workers)."""

    path: str
    obs_mode: str | None
    control_mode: str | None
    env_kwargs: dict[str, Any]
    tolerances: Tolerances
    sim_backend: str | None = None
    imports: tuple[str, ...] = ()
    trust_imports: bool = False
    """``--trust-recorded-imports``: the input's recorded imports may be imported (`resolve_task_imports`)."""
    converter: Callable[..., Any] | None = None
    keep: tuple[str, ...] = ("verified",)
    output: ReplayOutput | None = None
    """The output's spec (path, metadata changes): what a scratch episode is written as."""
    scratch: str | None = None
    """The run's scratch folder (`ScratchFolder`), where a worker writes an episode that is not next in the output's
    order; None: such an episode comes back whole."""
    block_rows: int | None = None
    scenes: dict[int, ScenePlace] = field(default_factory=dict)
    """Episode index → where its conversion ran, kept in its provenance (``"scene"``, `simreel.verdicts.scene_history`): a
    re-rendered episode is the recorded trajectory, so its scene is the input's; a control-mode conversion steps the
    episodes one after another in one env, so it ran in that run."""

    def open_worker(self) -> ConvertWorker:
        """The worker a pool process converts episodes in (`run_pool` calls it in each process)."""
        from simreel.replay.convert.worker import ConvertWorker

        return ConvertWorker(self)


def states_tolerances() -> Tolerances:
    return Tolerances.for_mode("states")


@dataclass
class ConvertResult(EpisodeResult):
    """What converting one episode gave (`EpisodeResult`: its report, and the converted episode whole, or the scratch
    recording holding it, or neither: it was written as it was converted), and what the worker decided: why `keep`
    leaves it out ("": it is written) and, when written, its arrays' `FieldHashes` digests, to check the output
    against."""

    left_out: str = ""
    digests: dict[str, str] = field(default_factory=dict)
