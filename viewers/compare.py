"""Recorded vs compared for the viewer (``--compare OTHER``): what OTHER is to the recording (`compared_role`: its
replay, its conversion, or another recording of the task), the core's comparison (`simreel.verdicts.compare`, the same numbers
`simreel replay` reports) placed on state rows, so the viewer can plot errors and mark the divergence, and the
explanation of that divergence (`simreel.verdicts.divergence`: events, error growth, and the cause `simreel replay -o`
classified and stored with the replayed episode, when OTHER is that replay).

The core reports a divergence by step (the outcome of step k is state row k + 1; ``at="reset"`` is row 0);
`divergence_row` converts. Episodes of different lengths are compared over the shorter one, a block of rows at a
time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simreel.datasets.provenance import provenance_tolerances
from simreel.formats.base import EpisodeRows, block_rows
from simreel.model.blocks import StepBlock
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel, RecordingMeta
from simreel.verdicts.compare import BlockComparison, Divergence, EpisodeComparison
from simreel.verdicts.divergence import Explanation, describe_divergence

__all__ = ["ViewComparison", "compare_for_view", "compared_role", "divergence_row", "explain_for_view",
           "judging_tolerances", "made_from", "DEFAULT_MODE"]

DEFAULT_MODE = "actions"
"""Whose default tolerances apply: `simreel replay --mode` (actions, states or step); actions is its default."""

_ROLES = {"replay": "replay", "convert": "conversion"}
"""`RecordingMeta.provenance` operation → what a file it made from the recording is to that recording."""


def divergence_row(d: Divergence) -> int:
    """The state row at which a divergence shows: 0 after reset, k + 1 for the outcome of step k."""
    return 0 if d.at == "reset" else d.step + 1


@dataclass
class ViewComparison:
    """A core `EpisodeComparison` and how its per-key errors map onto state rows."""

    comparison: EpisodeComparison
    steps: int
    """Steps compared (the shorter episode's length)."""
    note: str = ""
    """Why fewer steps were compared than the recording has, if so."""
    recorded_steps: int | None = None
    """The recording's steps (None: `steps`); more than `steps` when the replay is shorter."""
    judged_with: str = ""
    """Which tolerances judged it, where they are neither those asked for nor the default (`judging_tolerances`)."""

    @property
    def divergence(self) -> Divergence | None:
        return self.comparison.first_divergence

    @property
    def unchecked_steps(self) -> int:
        """Steps of the recording the replay does not reach, so never compared."""
        return max(0, (self.recorded_steps or self.steps) - self.steps)

    def verdict(self) -> str:
        """The verdict in words: the core's (``exact``, ``within tolerance``, ``diverged``), or, when the replay ends
        before the recording without diverging, ``incomplete`` with how far it holds: steps that were never
        compared are never called exact (``incomplete: exact for the first 20 of 30 steps``)."""
        verdict = self.comparison.verdict.replace("_", " ")
        if self.divergence is not None or not self.unchecked_steps:
            return verdict
        if not self.steps:
            return f"incomplete: {verdict} at the reset, none of the {self.recorded_steps} steps compared"
        return f"incomplete: {verdict} for the first {self.steps} of {self.recorded_steps} steps"

    def error_rows(self) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
        """`{key: (rows, errors, tolerance)}`: state and observation keys have a row per state (0..T), per-step keys
        (rewards, flags, info, contacts) one per step, placed at the row that step produced (1..T)."""
        out = {}
        for key, err in self.comparison.errors.items():
            start = 0 if len(err) == self.steps + 1 else 1
            out[key] = (np.arange(start, start + len(err)), err, self.comparison.tolerance[key])
        return out

    def plotted_keys(self) -> list[str]:
        """Keys worth a plot: those that are ever off at all; when none is (an exact replay), the state keys."""
        m = self.comparison.max_abs_error
        off = [k for k in self.comparison.errors if m.get(k, 0.0) > 0.0]
        return off or [k for k in self.comparison.errors if k.startswith("env_states/")]


def _rows(episode: Episode | EpisodeRows) -> EpisodeRows:
    return EpisodeRows.of(episode) if isinstance(episode, Episode) else episode


def judging_tolerances(asked: Tolerances | None, compared: RecordingMeta, recording: RecordingMeta,
                       path: str | Path) -> tuple[Tolerances, str]:
    """The tolerances that judge the file `compared` (its metadata) beside the recording `recording` at `path`, and
    a note saying what they are where that is not plain ("" otherwise), for the output.

    Those `asked` for (``--mode/--atol/--tol``) where some were. None asked for: where `compared` is a replay or a
    conversion of this very recording (`made_from`), the tolerances that judged it when it was written, so that its
    verdict here is that run's (a ``--mode step`` replay's are far wider than actions'); else `DEFAULT_MODE`'s."""
    if asked is not None:
        return asked, ""
    made = compared.provenance or {}
    defaults = Tolerances.for_mode(DEFAULT_MODE)
    if not compared_role(compared, recording, path):
        if made.get("operation") not in _ROLES or not made.get("source"):
            return defaults, ""
        return defaults, (f"the compared file is a {made['operation']} of another recording ({made['source']}): "
                          f"judged with the default tolerances (--mode {DEFAULT_MODE})")
    stored = provenance_tolerances(made)
    if stored is None:
        return defaults, ""
    tolerances, run, base = stored
    if tolerances.to_json() == defaults.to_json():
        return tolerances, ""
    changed = tolerances.overrides(base)
    return tolerances, (f"judged with the tolerances `{run}` judged it with when it wrote it"
                        + (f" ({changed} instead of its defaults)" if changed else ""))


def compared_role(compared: RecordingMeta, recording: RecordingMeta, path: str | Path) -> str:
    """What the file `compared` (its metadata) is to the recording `recording` at `path`: ``"replay"`` where
    ``simreel replay -o`` wrote it from this very recording (`made_from`), ``"conversion"`` where ``simreel convert``
    did, else ``""``: another recording of the task (a second ``simreel record`` run, a ManiSkill RecordEpisode file,
    a replay or conversion of another recording), which the viewer names by its file, never as a replay."""
    made = compared.provenance or {}
    role = _ROLES.get(made.get("operation"), "")
    return role if role and made.get("source") and made_from(made, recording, path) else ""


def made_from(made: Mapping[str, Any], recording: RecordingMeta, path: str | Path) -> bool:
    """Whether the provenance `made` (of a replay or a conversion) names the recording `recording` at `path` as its
    source: by its `RecordingMeta.recording_id` where both have one (a moved file is the same recording, a new one at
    the same path is not), else by the resolved path."""
    if made.get("source_recording_id") and recording.recording_id:
        return made["source_recording_id"] == recording.recording_id
    return Path(made["source"]).resolve() == Path(path).resolve()


def compare_for_view(
    recorded: Episode | EpisodeRows,
    compared: Episode | EpisodeRows,
    *,
    channels: Sequence[ContactChannel] = (),
    tolerances: Tolerances | None = None,
    rows: int | None = None,
) -> ViewComparison:
    """Compare with `simreel.verdicts.compare.BlockComparison` (the rule `simreel replay` judges by; default tolerances:
    those of `DEFAULT_MODE`) over the steps both episodes have, reading both `rows` steps at a time (None:
    `simreel.formats.base.block_rows` of the recording): only a block of each and the per-row error curves are held.
    Both are read front to back once, block beside block (an MCAP episode read by `steps` is scanned from its
    start for every block)."""
    recorded, compared = _rows(recorded), _rows(compared)
    steps = min(recorded.length, compared.length)
    note = ""
    if recorded.length != compared.length:
        note = (f"the compared episode has {compared.length} steps, the recording {recorded.length}: compared the "
                f"first {steps}")
    blocks = BlockComparison(tolerances or Tolerances.for_mode(DEFAULT_MODE), channels=channels)
    blocks.reset(recorded.reset(), compared.reset())
    if steps == 0:  # an episode of no steps still compares its (empty) per-step keys
        blocks.steps(recorded.steps(0, 0), compared.steps(0, 0))
    rows = rows or block_rows(recorded.fields)
    for (start, ours), (_, theirs) in zip(recorded.blocks(rows), compared.blocks(rows), strict=False):  # to the shorter
        blocks.steps(_first_rows(ours, steps - start), _first_rows(theirs, steps - start))
    return ViewComparison(blocks.comparison(), steps, note, recorded.length)


def _first_rows(block: StepBlock, n: int) -> StepBlock:
    """`block`, or its first `n` rows when it has more (the last block compared of the longer episode)."""
    return block if block.rows <= n else StepBlock.of({k: a[:n] for k, a in block.arrays.items()})


def explain_for_view(recorded: Episode, compared: Episode, comparison: ViewComparison,
                     channels: Sequence[ContactChannel] = (), *, role: str = "") -> Explanation | None:
    """The explanation of the viewer's first divergence: its events and error growth from the two episodes, and the
    cause that ``simreel replay -o`` classified and kept with the replayed episode (`EpisodeMeta.verification`) when
    `compared` is that replay of this recording (`role`: `compared_role`'s ``replay``) and its cause explains the
    same divergence (same step and key); None when nothing diverged. A replay of another recording explained that
    recording's divergence, not this one's."""
    explanation = describe_divergence(recorded, comparison.comparison, channels)
    if explanation is None:
        return None
    if role != "replay":
        explanation.checked.append("cause not classified: the compared file is no replay of this recording "
                                   "(`simreel replay -o` classifies the cause of its replays' divergences)")
        return explanation
    verification = compared.meta.verification
    stored = verification.explanation if verification is not None else None
    if not stored:
        explanation.checked.append("cause not classified: the replay holds no explanation (that replay did not "
                                   "diverge, or its file was rewritten without it)")
        return explanation
    try:
        replay = Explanation.from_json(stored)
    except (KeyError, TypeError, ValueError) as e:
        explanation.checked.append(f"cause not shown: the replay's explanation is malformed ({e!r})")
        return explanation
    d, r = explanation.divergence, replay.divergence
    if (r.step, r.at, r.key) == (d.step, d.at, d.key):
        explanation.cause = replay.cause
    else:
        explanation.checked.append(f"cause not shown: `simreel replay` explained another first divergence "
                                   f"({r.describe()}): other tolerances")
    return explanation
