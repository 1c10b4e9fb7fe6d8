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

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {
    "simreel.replay.audit.audit": ("AuditFinding", "AuditOptions", "AuditReport", "audit_task"),
    "simreel.replay.run.engine": ("EpisodeReplayer", "ReplayedEpisode"),
    "simreel.replay.run.replayer_options": ("ReplayerOptions",),
    "simreel.replay.run.options": ("MODES", "ReplayOptions"),
    "simreel.replay.report.report": ("EpisodeReport",),
    "simreel.replay.report.log": ("Verdicts", "read_verdicts"),
    "simreel.replay.report.tally": ("ReplayReport", "RunTally"),
    "simreel.replay.run.verify": ("ReplayRun", "verify_recording"),
    "simreel.replay.convert.convert": ("ConvertOptions", "convert_recording"),
}
"""Each public name and the module that defines it, imported on first use (so a command's options, which live in
light modules of this package, can be read without importing the whole room)."""
_HOME_OF = {name: module for module, names in _HOMES.items() for name in names}

__all__ = sorted(_HOME_OF)


def __getattr__(name: str) -> Any:
    if name in _HOME_OF:
        return getattr(importlib.import_module(_HOME_OF[name]), name)
    raise AttributeError(f"module 'simreel.replay' has no attribute {name!r}")
