"""Convert a recording to another observation mode and/or control mode, and prove each episode is still the
same trajectory: what `simreel convert IN OUT --obs-mode ... --control-mode ...` runs.

- **Observation mode** only (re-rendering, e.g. ``rgb``, ``pointcloud``): every recorded state is restored and the
  observations are computed from it (`EpisodeReplayer`, mode ``states``). The output keeps the input's states,
  actions, rewards and flags as they are (it adds only what the input lacks: rewards, success, fail recomputed
  from the states); the check: each restored state reads back within the ``states`` tolerances (a restore
  changes a state by <= 1.5e-8), the recomputed rewards and flags agree, and so do the recorded contact forces
  with those of one step simulated from the state (``states`` mode's 20 N); after writing, the output's states
  and actions are read back and must equal the input's exactly.
- **Control mode** (with or without a new observation mode): each recorded action is converted one step for
  one (`simreel.replay.convert.control`) and the converted actions are stepped from the episode's reset; the resulting
  trajectory is compared with the recorded one at every step (`simreel.replay.convert.tracking`: tool-centre pose,
  object poses, success timing), each episode getting its largest tracking errors, the first step one leaves
  its tolerance, and a verdict.

Filters: `episodes`, `count` (the first N of those are converted), `keep` (which of the converted episodes are
written: ``verified`` ones by default, also ``success``/``not_truncated`` ones if asked, or ``all``). The output's metadata says where it came from (`RecordingMeta.provenance`: source file,
episodes, the conversion, the tolerances) and each episode's verdict (`EpisodeMeta.provenance`). Episodes run in
this process and ``workers - 1`` more (`simreel.replay.run.pool.run_pool`).

Both read, convert, check and write an episode a block of rows at a time (the camera frames of a long episode never
sit in memory whole): into the output when the episode is next in its order, else into a scratch recording of its
own (`simreel.replay.run.output.ScratchEpisode`), copied in at its turn. What outlives a block is per-row errors, a
control-mode conversion's commanded poses and success flags (a few dozen bytes a step). The output is written in
the run's scratch folder, and every written episode read back from there a block at a time, its arrays' digests
compared with those of what was written (`simreel.datasets.digests.FieldHashes`), before the output is moved to its
name: one that fails the check is never published (`OutputCheckError`), and an old file it was to replace stays.

The run is `simreel.replay.convert.run.ConversionRun`; its workers `simreel.replay.convert.worker`, what they are
given `simreel.replay.convert.job`, where their rows go `simreel.replay.convert.sinks`, its report
`simreel.replay.convert.report`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from simreel.replay.convert.options import KEEP, ConvertOptions
from simreel.replay.convert.report import ConversionReport
from simreel.replay.convert.run import ConversionRun
from simreel.replay.report.report import EpisodeReport

__all__ = ["KEEP", "ConvertOptions", "convert_recording"]


def convert_recording(src: str | Path, dst: str | Path, options: ConvertOptions | None = None, *,
                      progress: Callable[[EpisodeReport], None] | None = None, **overrides: Any) -> ConversionReport:
    """Convert the recording `src` into a new recording `dst`: `ConversionRun(src, dst, options,
    **overrides).execute(progress)`; `overrides` are `ConvertOptions` fields, e.g.
    ``convert_recording("demos.h5", "ee.h5", control_mode="pd_ee_delta_pose", keep=["verified"])``."""
    with ConversionRun(src, dst, options, **overrides) as run:
        return run.execute(progress)
