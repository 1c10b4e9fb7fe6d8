"""Bad input to `simreel replay` / `simreel audit`: exit 2 and one line on stderr that says what and how to fix."""

from __future__ import annotations

import dataclasses

import pytest

from simreel.cli.main import main
from simreel.formats import open_reader, open_writer


@pytest.fixture(scope="module")
def rec(record):
    return record("PickCube-v1", 2, 20)


def _run(capsys, args):
    try:
        code = main(args)
    except SystemExit as e:  # argparse
        code = e.code
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize(
    "args,message",
    [
        (["replay", "{tmp}/nope.h5"], "nope.h5: no such file"),
        (["replay", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
        (["replay", "{rec}", "--episodes", "7"], "no episode 7 (episodes: 0, 1)"),
        (["replay", "{rec}", "--episodes", "x"], "bad episode list 'x'"),
        (["replay", "{rec}", "--mode", "states", "--resync", "5"], "--resync works with --mode actions only"),
        (["replay", "{rec}", "--resync", "0"], "--resync must be >= 1, got 0"),
        (["replay", "{rec}", "--workers", "0"], "--workers must be >= 1, got 0"),
        (["replay", "{rec}", "--atol", "-1"], "argument --atol: must be a finite number >= 0, got -1"),
        (["replay", "{rec}", "--tol", "speed=1"], "expected GROUP=NUMBER with GROUP one of pos"),
        (["replay", "{rec}", "--mode", "sideways"], "argument --mode: invalid choice: 'sideways'"),
        (["replay", "{rec}", "-o", "{rec}", "--overwrite"], "is the recording being replayed"),
        (["replay", "{rec}", "-o", "{tmp}/exists.h5"], "exists.h5 already exists; pass --overwrite"),
        (["replay", "{rec}", "-o", "{tmp}/out.txt"], "unknown recording suffix '.txt'"),
        (["replay", "{rec}", "--report", "{tmp}/no/dir/r.json"], "does not exist"),
        (["replay", "{rec}", "--import", "no_such_module_xyz"], "no module named 'no_such_module_xyz'"),
        (["audit", "PickCub-v1"], "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1"),
        (["audit", "PickCube-v1", "--steps", "0"], "--steps must be >= 1, got 0"),
        (["audit", "PickCube-v1", "--json", "{tmp}/no/dir/a.json"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, rec, args, message):
    (tmp_path / "junk.h5").write_bytes(b"not a recording at all")
    (tmp_path / "exists.h5").write_bytes(b"")
    args = [a.format(tmp=tmp_path, rec=rec) for a in args]
    code, err = _run(capsys, [*args, "-q"] if args[0] == "replay" else args)
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert message in err


def test_a_recording_of_another_layout_is_refused(tmp_path, capsys, rec):
    """A file whose episodes do not fit the env it names (another task version, a hand-edited file)."""
    bad = tmp_path / "mislabelled.h5"
    with open_reader(rec) as r, open_writer(bad, dataclasses.replace(r.meta, env_id="PushCube-v1")) as w:
        w.write_episode(r.read_episode(0))
    code, err = _run(capsys, ["replay", str(bad), "-q"])
    assert code == 2
    assert "the rebuilt PushCube-v1 has another state layout than the recording" in err
    assert "actors/goal_site: recorded (13,) float32, rebuilt absent" in err


def _relabelled(src, dst, **changes):
    """A copy of `src` whose recording metadata has `changes` (another task version, another machine)."""
    with open_reader(src) as r, open_writer(dst, dataclasses.replace(r.meta, **changes)) as w:
        for m in r.episodes:
            w.write_episode(r.read_episode(m.index))
    return dst


def test_a_user_error_with_workers_is_one_line_not_a_traceback(tmp_path, capsys, rec):
    """The parent builds its session before the pool: an --import the recording names that fails is exit 2."""
    bad = _relabelled(rec, tmp_path / "imports.h5", imports=["no_such_module_xyz"])
    code, err = _run(capsys, ["replay", str(bad), "--workers", "2", "-q"])
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "no module named 'no_such_module_xyz'" in err


def test_a_gpu_recording_on_a_machine_without_cuda_says_replay_on_the_cpu(tmp_path, capsys, rec):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA device: the GPU sim builds")
    gpu = _relabelled(rec, tmp_path / "gpu.h5", sim_backend="physx_cuda")
    code, err = _run(capsys, ["replay", str(gpu), "-q"])
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "recorded on the GPU sim (physx_cuda) and this machine has no CUDA device" in err
    assert "--sim-backend physx_cpu" in err and "different engines" in err
    code, err = _run(capsys, ["replay", str(gpu), "-q", "--sim-backend", "physx_cpu"])
    assert code == 0 and "sim backend: recorded physx_cuda, replaying physx_cpu" in err


def test_an_episode_of_inconsistent_length_is_a_simreel_error(tmp_path, rec):
    from simreel.errors import EpisodeLayoutError, SimreelError

    with open_reader(rec) as r:
        meta, ep = r.meta, r.read_episode(0)
    short = dataclasses.replace(ep, rewards=ep.rewards[:-1])
    with pytest.raises(EpisodeLayoutError, match=r"episode 0: rewards has 19 rows, expected 20") as info:
        short.check_shapes()
    assert isinstance(info.value, SimreelError)  # the CLI prints it as one line, exit 2
    with open_writer(tmp_path / "out.h5", meta) as w, pytest.raises(EpisodeLayoutError):
        w.write_episode(short)
