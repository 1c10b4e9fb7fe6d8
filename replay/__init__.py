"""simreel.replay: the replay-and-verify room — replay a recording in one of three modes (`MODES`: actions,
states, step; actions can also restore the recorded state every K steps, ``resync``), verify every step,
and audit a task for state that its state dict does not capture.

- `verify_recording(path, mode=..., resync=..., ...)` → `ReplayReport` (what `simreel replay` runs)
- `EpisodeReplayer(meta)`: one rebuilt env that reproduces each episode's reset and replays it
- `restore_state(unwrapped, flat_state)`: restore all of a recorded state (task, custom keys, controller)
- `audit_task(env_id, ...)` → `AuditReport` (what `simreel audit` runs)

The per-leaf comparison itself (tolerances, quaternion-aware errors, first divergence) is in the core,
`simreel.compare`, so the viewers can use it too. Importing this package imports neither mani_skill nor torch.
"""

from simreel.replay.audit import AuditFinding, AuditReport, audit_task
from simreel.replay.engine import MODES, EpisodeReplayer, ReplayedEpisode, ReplayError
from simreel.replay.restore import restore_state
from simreel.replay.verify import EpisodeReport, ReplayReport, verify_recording

__all__ = [
    "MODES",
    "AuditFinding",
    "AuditReport",
    "EpisodeReplayer",
    "EpisodeReport",
    "ReplayError",
    "ReplayReport",
    "ReplayedEpisode",
    "audit_task",
    "restore_state",
    "verify_recording",
]
