"""What a conversion says it checked (`simreel.replay.convert.convert`): the `checked:` line, the report's
conversion.checked and the output's provenance name only what the file held and was compared, as the per-episode
`checked` lists and the limits lines say."""

from __future__ import annotations

import pytest
from support.maniskill_files import record_maniskill

from simreel.formats import open_reader
from simreel.replay.convert.convert import convert_recording


@pytest.fixture(scope="module")
def without_rewards(tmp_path_factory):
    """A ManiSkill RecordEpisode file of 1 PickCube episode recorded without rewards (and, as ManiSkill's, without
    contact forces or fail flags)."""
    return record_maniskill(tmp_path_factory.mktemp("nr"), "PickCube-v1", name="nr", episodes=1, steps=5,
                            record_reward=False)


def test_a_re_render_claims_only_the_checks_it_made(without_rewards, tmp_path):
    """Regression: the checked line was a fixed text claiming rewards and contact forces were compared, beside
    limits lines saying the file holds neither."""
    out = tmp_path / "state.h5"
    report = convert_recording(without_rewards, out, obs_mode="state")
    assert report.ok
    assert "rewards not compared: the file holds none" in report.limits
    assert "contact forces not compared: the file holds none" in report.limits
    assert report.episodes[0].checked == ["env_states", "terminated", "truncated", "success"]
    checked = report.conversion["checked"]
    assert checked == ("per step, each restored state read back within the 'states' tolerances, recomputed flags "
                       "(terminated, truncated, success); the output's states and actions equal the input's")
    assert f"checked: {checked}" in report.summary()
    with open_reader(out) as r:
        assert r.meta.provenance["conversion"]["checked"] == checked


def test_a_re_render_of_a_full_recording_names_every_check(record, tmp_path):
    report = convert_recording(record("PickCube-v1", 1, 5), tmp_path / "state.h5", obs_mode="state")
    assert report.ok and report.limits == []
    assert report.episodes[0].checked == ["env_states", "contacts", "info", "rewards", "terminated", "truncated",
                                          "success", "fail"]
    assert report.conversion["checked"] == (
        "per step, each restored state read back within the 'states' tolerances, recorded contact forces against "
        "one step simulated from the state, recorded info, recomputed rewards, recomputed flags (terminated, "
        "truncated, success, fail); the output's states and actions equal the input's")
