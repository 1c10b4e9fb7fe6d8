"""Unseeded resets told at record time: the recorder counts the episodes a reset began without a seed and those a
replay remakes (their random generators' states captured: on the CPU sim with one env, exact), and warns, once,
only where a replay cannot remake them (several envs, the GPU sim: see test_record_wrapper_gpu.py)."""

from __future__ import annotations

import warnings

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env


def _record(path, resets):
    rec = RecordWrapper(make_env("PickCube-v1", render_backend="none"), path)
    rec.action_space.seed(0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for seed in resets:
            rec.reset(seed=seed)
            for _ in range(8):
                rec.step(rec.action_space.sample())
        rec.close()
    return rec, [str(w.message) for w in caught if "without a seed" in str(w.message)]


def test_unseeded_episodes_on_one_cpu_env_are_counted_replay_exact_and_are_not_warned_of(tmp_path, capsys):
    path = tmp_path / "rl.h5"
    rec, warned = _record(path, [0, None, None])
    assert (rec.unseeded, rec.unseeded_remade) == (2, 2) and warned == []
    with open_reader(path) as r:
        assert [m.seed for m in r.episodes] == [0, None, None]
        assert all(m.reset_generators for m in r.episodes[1:])
    capsys.readouterr()
    assert main(["replay", str(path), "-q"]) == 0
    assert "3 of 3 episode(s) verified (3 exact, 0 within tolerance)" in capsys.readouterr().out


def test_seeded_episodes_count_none(tmp_path):
    rec, warned = _record(tmp_path / "seeded.h5", [0, 1])
    assert (rec.unseeded, rec.unseeded_remade) == (0, 0) and warned == []
