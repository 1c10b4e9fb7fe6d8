"""A recording holding NaN or an infinity is never verified: in every mode, a value that is not finite fails the
check that reads it, even where the replay reads back the same value (a static or kinematic body's restored
position does)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from simreel.cli.main import main
from simreel.formats import open_reader, open_writer


@pytest.fixture(scope="module")
def poisoned(record, tmp_path_factory):
    """PickCube-v1, one episode, with its kinematic goal_site's x at state row 3 set to NaN (or inf)."""
    src = record("PickCube-v1", 1, 6)
    out = {}
    for name, bad in (("nan", np.nan), ("inf", np.inf)):
        with open_reader(src) as r:
            meta, ep = r.meta, r.read_episode(0)
        states = {k: v.copy() for k, v in ep.env_states.items()}
        states["actors/goal_site"][3, 0] = bad
        out[name] = tmp_path_factory.mktemp("poisoned") / f"{name}.h5"
        with open_writer(out[name], meta, overwrite=True) as w:
            w.write_episode(dataclasses.replace(ep, env_states=states))
    return out


@pytest.mark.parametrize("value", ["nan", "inf"])
@pytest.mark.parametrize("mode", ["states", "step", "actions"])
def test_a_non_finite_restored_position_diverges_in_every_mode(poisoned, tmp_path, capsys, mode, value):
    report = tmp_path / "r.json"
    assert main(["replay", str(poisoned[value]), "--mode", mode, "--report", str(report), "-q"]) == 1
    episode = json.loads(report.read_text())["episodes"][0]
    assert episode["verdict"] == "diverged"
    assert episode["first_divergence"]["key"] == "env_states/actors/goal_site[p]"
    assert episode["first_divergence"]["error"] == "inf"
    capsys.readouterr()


def test_a_conversion_does_not_call_it_verified_and_filter_does_not_keep_it(poisoned, tmp_path, capsys):
    """What reads the verdicts keeps to them: a conversion leaves the episode out, or with --keep all writes it as
    diverged; filter --verified drops it."""
    report = tmp_path / "r.json"
    out = tmp_path / "c.h5"
    assert main(["convert", str(poisoned["nan"]), str(out), "--obs-mode", "state", "--report", str(report), "-q"]) == 1
    assert not out.exists()
    assert main(["convert", str(poisoned["nan"]), str(out), "--obs-mode", "state", "--keep", "all", "-q"]) == 1
    with open_reader(out) as r:
        assert r.episode_meta(0).provenance.verdict == "diverged"
    assert main(["replay", str(poisoned["nan"]), "--mode", "states", "--report", str(tmp_path / "v.json"),
                 "-q"]) == 1
    assert main(["filter", str(poisoned["nan"]), "-o", str(tmp_path / "ok.h5"), "--verified",
                 str(tmp_path / "v.json"), "-q"]) == 2
    assert "nothing matches" in capsys.readouterr().err
