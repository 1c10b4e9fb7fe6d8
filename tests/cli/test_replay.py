"""`simreel replay` on recordings it cannot replay as they are: another layout, a GPU recording without CUDA,
user errors in worker processes, episodes of inconsistent length."""

from __future__ import annotations

import dataclasses
import resource
import subprocess
import sys

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


def _limit_memory() -> None:
    """In the child: 3 GB of address space, enough to start simreel and replay, not to hold billions of indices."""
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))


@pytest.mark.parametrize("episodes", ["0-5000000000", "1,0-99999999999999999999"])
def test_a_huge_episode_range_costs_no_memory_and_is_refused_as_a_short_one(rec, episodes):
    """`--episodes 0-5000000000` is two numbers, never a list of billions (a MemoryError, an OverflowError past the
    C size: exit 3): the range is walked to the first episode the file lacks, and refused there in one line, as
    ``--episodes 0-2`` is."""
    done = subprocess.run([sys.executable, "-m", "simreel", "replay", str(rec), "-q", "--episodes", episodes],
                          capture_output=True, text=True, timeout=300, preexec_fn=_limit_memory)
    assert (done.returncode, done.stderr) == (2, f"simreel replay: error: {rec}: no episode 2 (episodes: 0, 1)\n")


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
    code, err = _run(capsys, ["replay", str(bad), "--workers", "2", "-q", "--trust-recorded-imports"])
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "the recording's --import no_such_module_xyz is not found here (tried module no_such_module_xyz" in err


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


def test_off_a_terminal_replay_progress_is_a_line_now_and_then_naming_the_last_verdict(capsys, monkeypatch, rec):
    """A short replay off a terminal writes nothing to stderr (each episode's verdict does not redraw the bar there);
    with `LOG_LINE_SECONDS` at 0 every episode is a plain line ending with the last episode's verdict."""
    import re

    import simreel.cli.common as common

    assert _run(capsys, ["replay", str(rec)]) == (0, "")
    monkeypatch.setattr(common, "LOG_LINE_SECONDS", 0.0)
    code, err = _run(capsys, ["replay", str(rec)])
    assert code == 0
    lines = err.splitlines()
    assert [re.search(r"\| (\d)/2 \[", line).group(1) for line in lines] == ["0", "1", "2"], err
    assert lines[1].endswith("0 exact]") and lines[2].endswith("1 exact]"), err
