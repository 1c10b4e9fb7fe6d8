"""simreel.replay: the replay-and-verify room — replay a recording in one of three modes (`MODES`: actions,
states, step; actions can also restore the recorded state every K steps, ``resync``), verify every step,
and audit a task for state that its state dict does not capture.

- `ReplayRun(inputs, options).execute()` → `RunTally`: what `simreel replay` runs over recordings, folders and
  patterns (local worker processes or Ray; a streaming, resumable report); `ReplayOptions` holds its options
- `verify_recording(path, mode=..., resync=..., ...)` → `ReplayReport`: one recording, every episode's report kept.
  A diverged episode's report explains why (`simreel.replay.explain.explain`: events, error growth, the cause the data
  supports), and every episode's scene is compared with the recorded scene fingerprint at its reset
- `read_verdicts(report)` → `Verdicts`: the verdicts a replay report holds (for filtering a dataset by them)
- `EpisodeReplayer(meta)`: one rebuilt env that reproduces each episode's reset and replays it
- `audit_task(env_id, ...)` → `AuditReport` (what `simreel audit` runs), with ``policy=`` or ``trajectory=``
  also along real trajectories (`simreel.replay.audit.trajectory`)

Restoring a recorded state (`simreel.sim.state.restore_state`) and the per-leaf comparison (`simreel.verdicts.compare`:
tolerances, quaternion-aware errors, first divergence) are in the core, so the viewers use them too.
Importing this package imports neither mani_skill nor torch.
"""

from simreel.replay.audit.audit import AuditFinding, AuditOptions, AuditReport, audit_task
from simreel.replay.report.log import Verdicts, read_verdicts
from simreel.replay.report.report import EpisodeReport
from simreel.replay.report.tally import ReplayReport, RunTally
from simreel.replay.run.engine import MODES, EpisodeReplayer, ReplayedEpisode, ReplayerOptions
from simreel.replay.run.verify import ReplayOptions, ReplayRun, verify_recording

__all__ = [
    "MODES",
    "AuditFinding",
    "AuditOptions",
    "AuditReport",
    "EpisodeReplayer",
    "EpisodeReport",
    "ReplayOptions",
    "ReplayReport",
    "ReplayRun",
    "ReplayedEpisode",
    "ReplayerOptions",
    "RunTally",
    "Verdicts",
    "audit_task",
    "read_verdicts",
    "verify_recording",
]
