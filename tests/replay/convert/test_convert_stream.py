"""A re-render (`simreel convert --obs-mode`) reads, restores, checks and writes each episode a block of rows at a
time: here, into the output; in worker processes (and here, for an episode whose turn has not come), into scratch
recordings copied in at their turn. Either way the output is the same, byte for byte, `keep` leaves out what it
should, nothing of the scratch folder stays, and no episode is ever read whole. Re-rendered to ``state``
observations (no camera: the cameras' own path is `test_convert_render.py`'s)."""

from __future__ import annotations

import h5py
import pytest
from support.maniskill_files import record_maniskill

from simreel.datasets.digests import field_digests
from simreel.formats import open_reader
from simreel.formats.base import EpisodeRows
from simreel.replay.convert.convert import convert_recording
from simreel.replay.run.output import scratch_folder

STEPS = 10
BLOCK = 3
"""Steps per block: 10-step episodes go in four blocks, the last one short."""


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """3 PickCube demos (RecordEpisode, no observations); episode 1's reward at step 4 is not the one its state
    gives, so a re-render finds it diverged."""
    path = record_maniskill(tmp_path_factory.mktemp("demos"), "PickCube-v1", name="demos", episodes=3, steps=STEPS,
                            path="pick")
    with h5py.File(path, "r+") as f:
        f["traj_1/rewards"][4] += 0.5
    return path


def _digests(path) -> dict[int, dict[str, str]]:
    with open_reader(path) as r:
        return {m.index: field_digests(r.open_episode(m.index)) for m in r.episodes}


def _states_and_actions(digests: dict[str, str]) -> dict[str, str]:
    return {k: d for k, d in digests.items() if k.startswith("env_states/") or k == "actions"}


def test_a_re_render_writes_the_same_file_from_one_process_or_two(demos, tmp_path):
    one = convert_recording(demos, tmp_path / "one.h5", obs_mode="state", keep=["verified"], block_rows=BLOCK)
    two = convert_recording(demos, tmp_path / "two.h5", obs_mode="state", keep=["verified"], block_rows=BLOCK,
                            workers=2)
    for report in (one, two):
        assert [e.ok for e in report.episodes] == [True, False, True] and report.episodes[1].verdict == "diverged"
        assert report.episodes[1].first_divergence.key == "rewards" and report.episodes[1].first_divergence.step == 4
        assert report.written == [0, 2] and report.dropped == {1: "not verified (diverged)"}
        assert not report.ok and not report.written_mismatch and "byte-identical" in report.written_check
    assert not scratch_folder(tmp_path / "two.h5").exists()
    written, source = _digests(tmp_path / "one.h5"), _digests(demos)
    assert list(written) == [0, 2] and _digests(tmp_path / "two.h5") == written
    for index, fields in written.items():
        assert _states_and_actions(fields) == _states_and_actions(source[index])  # the input's, exactly
        assert any(k.startswith("obs/") for k in fields) and not any(k.startswith("obs/") for k in source[index])
    with open_reader(tmp_path / "one.h5") as r:
        report = one
        assert r.meta.obs_mode == "state" and r.meta.provenance["filters"]["keep"] == ["verified"]
        episode = r.read_episode(2)
        assert episode.meta.provenance.verdict == report.episodes[2].verdict and episode.length == STEPS
        assert next(iter(episode.obs.values())).shape[0] == STEPS + 1


def test_a_re_render_that_keeps_nothing_writes_no_file(demos, tmp_path):
    report = convert_recording(demos, tmp_path / "none.h5", obs_mode="state", keep=["success"], block_rows=BLOCK)
    assert report.written == [] and report.dropped[1] == "not verified (diverged)"  # verified first, then success
    assert {report.dropped[0], report.dropped[2]} == {"no success at its last step"}
    assert report.written_check == "nothing written" and not (tmp_path / "none.h5").exists()


def test_a_re_render_never_reads_an_episode_whole(demos, tmp_path, monkeypatch):
    def whole(self, *args, **kwargs):
        raise AssertionError(f"episode {self.meta.index} read whole")

    monkeypatch.setattr(EpisodeRows, "episode", whole)
    report = convert_recording(demos, tmp_path / "blocks.h5", obs_mode="state", block_rows=BLOCK, keep="all")
    assert report.written == [0, 1, 2] and not report.written_mismatch


def _judged(report) -> dict:
    """An episode's report but for its timing."""
    return {k: v for k, v in report.to_json().items() if k != "seconds"}


def test_a_control_mode_conversion_in_blocks_is_the_one_made_whole(demos, tmp_path, monkeypatch):
    """Tracking errors taken a block at a time are those of the whole episode, and the files are the same."""
    whole = convert_recording(demos, tmp_path / "whole.h5", control_mode="pd_ee_delta_pose")
    two = convert_recording(demos, tmp_path / "two.h5", control_mode="pd_ee_delta_pose", block_rows=BLOCK,
                            workers=2)

    def read_whole(self, *args, **kwargs):
        raise AssertionError(f"episode {self.meta.index} read whole")

    monkeypatch.setattr(EpisodeRows, "episode", read_whole)
    blocks = convert_recording(demos, tmp_path / "blocks.h5", control_mode="pd_ee_delta_pose", block_rows=BLOCK)
    assert whole.ok and whole.written == [0, 1, 2] and not whole.written_mismatch
    for report in (blocks, two):
        assert [_judged(e) for e in report.episodes] == [_judged(e) for e in whole.episodes]
        assert report.written == whole.written and not report.written_mismatch
    assert max(whole.episodes[0].per_step["ee/panda_hand_tcp[p]"]) > 0  # an ee controller reaches it another way
    assert len(whole.episodes[0].per_step["success"]) == STEPS
    assert _digests(tmp_path / "blocks.h5") == _digests(tmp_path / "whole.h5") == _digests(tmp_path / "two.h5")
    assert not scratch_folder(tmp_path / "two.h5").exists()
