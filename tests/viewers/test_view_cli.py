"""`simreel view`: saving a session, one-line errors with exit status 2, and a cheap `import simreel`."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from simreel.cli.main import main


def test_view_save(pickcube_h5, tmp_path, capsys, rrd_reader):
    out = tmp_path / "out" / "pc.rrd"
    assert main(["view", str(pickcube_h5), "--save", str(out), "--geometry", "collision", "--episode", "0"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    rrd = rrd_reader(out)
    assert "/world/cube" in rrd.data and rrd.blueprint_views


def test_view_defaults_to_saving_without_a_display(pickcube_h5, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["view", str(pickcube_h5), "--geometry", "collision"]) == 0
    assert (tmp_path / "pickcube.episode0.rrd").is_file()
    assert "open it with: rerun" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--episode", "7"], "no episode 7 (episodes: 0)"),
        (["--save", "x.png"], "--save x.png: the output must end in .rrd"),
        (["--block-steps", "0"], "--block-steps must be ≥ 1, got 0"),
        (["--compare", "missing.h5"], "missing.h5: no such file"),
    ],
)
def test_view_errors_are_one_line(pickcube_h5, extra, message, capsys):
    assert main(["view", str(pickcube_h5), "--geometry", "collision", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("simreel view: error: ") and message in err and err.count("\n") == 1


def test_compare_with_another_env_is_refused(pickcube_h5, tmp_path, capsys):
    import dataclasses

    from simreel.formats import open_reader, open_writer

    with open_reader(pickcube_h5) as r:
        meta, ep = dataclasses.replace(r.meta, env_id="PushCube-v1"), r.read_episode(0)
    other = tmp_path / "other.h5"
    with open_writer(other, meta) as w:
        w.write_episode(ep)
    assert main(["view", str(pickcube_h5), "--compare", str(other), "--geometry", "collision"]) == 2
    assert "it is a recording of PushCube-v1, not of PickCube-v1" in capsys.readouterr().err


def test_import_simreel_and_cli_stay_free_of_rerun_and_mani_skill():
    code = (
        "import sys, simreel, simreel.cli.main as m; m.build_parser(); import simreel.viewers; "
        "bad = [n for n in ('rerun', 'mani_skill', 'sapien') if n in sys.modules]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ})


def test_view_mcap_recording(pickcube_h5, tmp_path, rrd_reader):
    from simreel.formats import open_reader, open_writer

    mcap = tmp_path / "pickcube.mcap"
    with open_reader(pickcube_h5) as r, open_writer(mcap, r.meta) as w:
        w.write_episode(r.read_episode(0))
    out = tmp_path / "mcap.rrd"
    assert main(["view", str(mcap), "--save", str(out), "--geometry", "collision"]) == 0
    rrd = rrd_reader(out)
    assert rrd.recording_ids == ["pickcube.mcap#episode-0"]
    assert rrd.steps("/world/cube", "Transform3D:translation") == list(range(-1, 30))
