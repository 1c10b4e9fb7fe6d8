"""An episode recorded after an unseeded reset replays from its recorded initial state, and says so."""

from __future__ import annotations

import json

import numpy as np

from simreel.cli.main import main
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env


def test_unseeded_episode_replays_from_its_initial_state(tmp_path, capsys):
    rec = RecordWrapper(make_env("PushCube-v1", render_backend="none"), tmp_path / "u.h5")
    rec.reset(seed=3)
    rec.reset()  # unseeded: ManiSkill draws this episode from the global RNG
    rng = np.random.default_rng(0)
    for _ in range(15):
        rec.step(rng.uniform(-1, 1, size=rec.action_space.shape).astype(np.float32))
    rec.close()
    code = main(["replay", str(tmp_path / "u.h5"), "--report", str(tmp_path / "r.json"), "-q"])
    report = json.loads((tmp_path / "r.json").read_text())
    (episode,) = report["episodes"]
    assert code == 0, capsys.readouterr()
    assert episode["verdict"] in ("exact", "within_tolerance")
    assert any("no seed" in x for x in episode["limits"])
    assert any("recorded initial state" in x for x in episode["limits"])
