"""Verdicts on recordings that hold what no replay can reproduce: quaternions that are no rotation, info entries
the replaying task no longer returns (real ManiSkill envs, every mode)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from simreel.formats import open_reader, open_writer
from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.state_tree import LeafSpec
from simreel.replay.run.engine import MODES, EpisodeReplayer
from simreel.replay.run.verify import verify_recording
from simreel.verdicts.compare import compare_episode

CUBE_Q = "env_states/actors/cube[q]"


def _rewrite(src: Path, dst: Path, change: Callable[[Episode], None], *, episodes: tuple[int, ...] = (1,),
             info: dict[str, LeafSpec] | None = None) -> Path:
    """A copy of the recording `src` with `change` applied to `episodes` (and `info` added to its info layout)."""
    with open_reader(src) as reader:
        meta = dataclasses.replace(reader.meta, info_layout={**reader.meta.info_layout, **(info or {})})
        with open_writer(dst, meta) as writer:
            for m in reader.episodes:
                episode = reader.read_episode(m.index)
                if m.index in episodes:
                    change(episode)
                writer.write_episode(episode)
    return dst


@pytest.mark.parametrize("scale", [0.0, 2.0])
@pytest.mark.parametrize("mode", MODES)
def test_recorded_quaternions_that_are_no_rotation_never_verify(record, tmp_path, mode, scale):
    """Zeroed or doubled, the cube's recorded quaternions were called exact (normalised, [0,0,0,0] is 0 rad from
    anything) or within tolerance; a states replay restores them as they are, so even equal sides must not pass."""

    def scale_cube_q(episode: Episode) -> None:
        episode.env_states["actors/cube"][:, 3:7] *= scale

    path = _rewrite(record("SimreelLiftCube-v1", 2, 6), tmp_path / f"q{scale}.h5", scale_cube_q)
    first, second = verify_recording(path, mode=mode).episodes
    assert first.verdict in ("exact", "within_tolerance")
    assert second.verdict == "diverged"
    d = second.first_divergence
    assert (d.at, d.key) == ("reset", CUBE_Q) and math.isinf(d.error)


def test_recorded_info_the_task_no_longer_returns_is_named_never_checked(record, tmp_path):
    """A recorded info entry the replaying task returns at no step was compared with the zeros its rows were filled
    with, and called exact; now it is named not compared, as an observation the replay lacks is, and the verdict
    holds for what was compared."""
    added = {"collided": LeafSpec((), "bool"), "penalty": LeafSpec((), "float32")}

    def add_info(episode: Episode) -> None:
        episode.info.update(collided=np.zeros(episode.length, bool), penalty=np.zeros(episode.length, np.float32))

    path = _rewrite(record("SimreelLiftCube-v1", 2, 6), tmp_path / "more_info.h5", add_info, episodes=(0, 1),
                    info=added)
    lines = [f"info/{key} not compared: the replay's info has no such key" for key in added]
    for mode in MODES:
        report = verify_recording(path, mode=mode)
        for episode in report.episodes:
            assert episode.ok and (mode != "actions" or episode.verdict == "exact")
            assert all(line in episode.limits for line in lines), episode.limits
            assert not {f"info/{key}" for key in added} & set(episode.max_abs_error)
            assert "info/is_grasped" in episode.max_abs_error  # the info the task returns is still compared
    with open_reader(path) as reader, EpisodeReplayer(reader.meta) as replayer:  # in memory, as explanations replay
        recorded = reader.read_episode(0)
        replayed = replayer.replay(recorded).episode
    assert set(recorded.info) - set(replayed.info) == set(added)
    assert compare_episode(recorded, replayed, Tolerances.for_mode("actions")).not_compared == lines
