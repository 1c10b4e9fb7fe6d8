"""What a training set holds (`SampleOptions`): the features, the windows, and which episodes (`EpisodeChoice`: a
replay report's verdicts, a split by episode), each checked when given (`UsageError` naming it and what to give)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from simreel.errors import UsageError
from simreel.options.checks import text_tuple, whole_number
from simreel.training.windows import ACTION_PADS
from simreel.verdicts.report_file import REPORT_VERDICTS, VERIFIED

__all__ = ["EpisodeChoice", "SampleOptions", "SPLITS", "DEFAULT_FEATURES"]

SPLITS = ("train", "val")
"""The two sides of a split by episode (`simreel.training.episodes.split_episodes`)."""
DEFAULT_FEATURES = ("env_states", "actions")
"""What a sample holds unless told: every state leaf and the actions (every simreel recording has both)."""


@dataclass(frozen=True)
class EpisodeChoice:
    """Which episodes of the recordings a training set or an export takes.

    Attributes:
        report: a `simreel replay --report` file; only the episodes whose verdict is one of `keep` are taken.
        keep: the verdicts to take with `report` (default: the verified ones, exact and within_tolerance).
        split: "train", "val" or None (every episode): one side of a split by episode.
        val_fraction: the share of episodes "val" gets (at least one where there are two or more).
        seed: the seed of the split's shuffle (the same seed, the same split, in every process).
    """

    report: str | Path | None = None
    keep: tuple[str, ...] = VERIFIED
    split: str | None = None
    val_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.report is not None and not isinstance(self.report, (str, Path)):
            raise UsageError(f"report={self.report!r}: give the path of a `simreel replay --report` file, or None")
        if isinstance(self.keep, str) or not self.keep or not all(v in REPORT_VERDICTS for v in self.keep):
            raise UsageError(f"keep={self.keep!r}: give a tuple of verdicts among {', '.join(REPORT_VERDICTS)} "
                             "(the default keeps the verified ones: exact, within_tolerance)")
        object.__setattr__(self, "keep", tuple(self.keep))
        if self.split is not None and self.split not in SPLITS:
            raise UsageError(f"split={self.split!r}: give 'train', 'val' or None (every episode)")
        if isinstance(self.val_fraction, bool) or not isinstance(self.val_fraction, (int, float)) or not (
                0.0 < self.val_fraction < 1.0):
            raise UsageError(f"val_fraction={self.val_fraction!r}: give a fraction between 0 and 1, e.g. 0.2")
        whole_number("seed", self.seed, "a whole number")


@dataclass(frozen=True)
class SampleOptions:
    """What each sample of a `RecordingDataset` holds.

    Attributes:
        features: field names or groups (`simreel.training.features`); a file lacking one is a `RecordingFileError`
            naming it and the episode.
        history: per-state rows a sample (the step's own and those before it).
        horizon: per-step rows a sample (the step's own and those after it: an action chunk).
        action_pad: how actions past an episode's end are padded: "auto" (by control mode), "edge" or "hold"
            (`simreel.training.windows.ACTION_PADS`).
        episodes: which episodes (`EpisodeChoice`).
        cache_bytes: bytes of blocks kept per process (`simreel.training.blocks`).
    """

    features: tuple[str, ...] = DEFAULT_FEATURES
    history: int = 1
    horizon: int = 1
    action_pad: str = "auto"
    episodes: EpisodeChoice = field(default_factory=EpisodeChoice)
    cache_bytes: int = 64 << 20

    def __post_init__(self) -> None:
        object.__setattr__(self, "features", text_tuple("features", self.features, "field names, e.g. "
                                                        "['obs/agent/qpos', 'actions']"))
        if not self.features:
            raise UsageError("features=(): name at least one field, e.g. ['obs/agent/qpos', 'actions']")
        for name in ("history", "horizon"):
            whole_number(name, getattr(self, name), "a whole number of steps >= 1", minimum=1)
        if self.action_pad not in ACTION_PADS:
            raise UsageError(f"action_pad={self.action_pad!r}: give one of {', '.join(ACTION_PADS)}")
        if not isinstance(self.episodes, EpisodeChoice):
            raise UsageError(f"episodes={self.episodes!r}: give an EpisodeChoice, e.g. EpisodeChoice(split='train')")
        whole_number("cache_bytes", self.cache_bytes, "a whole number of bytes >= 1", minimum=1)
