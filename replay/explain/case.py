"""The diverged episode an explanation is about (`Case`): the replayer, the two episodes, their comparison, how the
replay ran (`ExplainContext`), and the explanation being built, whose ``checked`` list each check adds to."""

from __future__ import annotations

from dataclasses import dataclass, field

from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel
from simreel.replay.run.engine import EpisodeReplayer, ReplayedEpisode
from simreel.verdicts.compare import EpisodeComparison
from simreel.verdicts.divergence import describe_divergence

__all__ = ["ExplainContext", "Case", "NEIGHBOURS", "NO_STATES"]

NEIGHBOURS = 2
"""Steps on each side of the divergent step whose one-step errors are checked."""
NO_STATES = ("the file holds no states: the one-step errors, the second instance, the reset's state and the other "
             "control modes need them and were not checked, and where a state difference began cannot be told")


@dataclass(frozen=True)
class ExplainContext:
    """What an explanation needs besides the two episodes: how the replay ran and what differed before it ran."""

    mode: str
    resync: int | None
    channels: list[ContactChannel]
    env_id: str
    build_differences: list[str] = field(default_factory=list)
    """Version, sim backend and sim config differences (`simreel.replay.run.fingerprint.fingerprint_differences`)."""


class Case:
    """One diverged episode, and its explanation so far: the data part (`describe_divergence`) first."""

    def __init__(self, replayer: EpisodeReplayer, recorded: Episode, replayed: ReplayedEpisode,
                 cmp: EpisodeComparison, ctx: ExplainContext) -> None:
        self.replayer = replayer
        self.recorded = recorded
        self.replayed = replayed
        self.cmp = cmp
        self.ctx = ctx
        self.explanation = describe_divergence(recorded, cmp, ctx.channels, steps_on=self.steps_on)
        d = cmp.first_divergence
        self.step = -1 if d.at == "reset" else d.step
        """The divergent step (-1: the reset)."""

    @property
    def checked(self) -> list[str]:
        return self.explanation.checked

    @property
    def has_states(self) -> bool:
        """Whether the recording holds env states (a ManiSkill file recorded with record_env_state=False holds none)."""
        return bool(self.recorded.env_states)

    @property
    def steps_on(self) -> bool:
        """Whether the replay stepped on from its own states, so a difference could grow across steps (``actions``,
        with or without ``--resync``); in ``step`` and ``states`` mode every step starts from a restored state."""
        return self.ctx.mode == "actions"

    def window(self, k: int | None = None) -> list[int]:
        """Step k (None: the divergent step) and its `NEIGHBOURS` on each side that the episode has."""
        k = self.step if k is None else k
        return [t for t in range(k - NEIGHBOURS, k + NEIGHBOURS + 1) if 0 <= t < self.recorded.length]
