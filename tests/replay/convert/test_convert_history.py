"""A control-mode conversion and the scene's history (`simreel.replay.run.history`): its output replays exactly, in
recorded order, only when the conversion stepped its episodes one after another in one scene, as the replay does."""

from __future__ import annotations

import json

from support.maniskill_files import record_maniskill

from simreel.cli.main import main


def test_a_control_mode_conversion_asked_for_workers_runs_in_one_process(tmp_path, capsys):
    """Regression: with --workers 2 each process converted some episodes after others than the output holds before
    them; a grasp episode of the output then diverged from its own replay (PhysX results depend on the history)."""
    src = record_maniskill(tmp_path, "PickCube-v1", name="pick", episodes=4, steps=60, path="pick")
    out = tmp_path / "ee.h5"
    assert main(["convert", str(src), str(out), "--control-mode", "pd_ee_delta_pose", "--workers", "2", "-q"]) == 0
    assert "converted in one process, not 2" in capsys.readouterr().err
    assert main(["replay", str(out), "-q"]) == 0
    assert "4 exact" in capsys.readouterr().out


def test_an_episode_whose_predecessors_the_conversion_left_out_says_so(tmp_path):
    """The limit names the conversion that left them out, not the output file as if another recording."""
    src = record_maniskill(tmp_path, "PickCube-v1", name="pick", episodes=4, steps=60, path="pick")
    out, report = tmp_path / "kept.h5", tmp_path / "r.json"
    assert main(["convert", str(src), str(out), "--control-mode", "pd_ee_delta_pose", "--keep", "success", "-q"]) == 0
    main(["replay", str(out), "--report", str(report), "-q"])  # episode 2 of 0-3, the one successful
    (episode,) = json.loads(report.read_text())["episodes"]
    assert ("replayed on a rebuilt scene without the 2 episode(s) that ran in its scene before it when this file's "
            "conversion stepped them (from episode 0): the conversion left some of them out of this file (--keep, or "
            "a failed episode)") in episode["limits"][0]


def test_a_re_render_finds_its_input_scene_chains_once(record, tmp_path, monkeypatch):
    """The run found them for the episodes' scenes, and its worker again for the steps before their resets: O(episodes)
    twice, 0.4 s of 100,000 episodes."""
    import simreel.replay.convert.run as run
    from simreel.verdicts.scene_history import SceneChains

    built = []

    class CountedChains(SceneChains):  # the real chains, counted
        def __init__(self, episodes):
            built.append(len(episodes))
            super().__init__(episodes)

    monkeypatch.setattr(run, "SceneChains", CountedChains)
    src = record("PickCube-v1", 3, 5, "--record-obs")
    assert main(["convert", str(src), str(tmp_path / "out.h5"), "--obs-mode", "state_dict", "-q"]) == 0
    assert built == [3]
