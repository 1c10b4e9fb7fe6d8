"""`--import` on every command that builds an env, and a custom task's recording replayed, viewed and converted
from other folders than the one it was recorded in: real subprocesses, a task defined in a temporary .py file."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from support.processes import simreel_command

from simreel.cli.main import build_parser

TASK = '''
from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
from mani_skill.utils.registration import register_env


@register_env("MyMovablePick-v1", max_episode_steps=50)
class MyMovablePick(PickCubeEnv):
    pass
'''


def _simreel(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(simreel_command(*args), cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("command", ["record", "replay", "audit", "view", "convert"])
def test_every_command_that_builds_an_env_takes_import(command):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    assert "--import" in sub._option_string_actions


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """project/data/run.h5, recorded in project/data with `--import my_tasks.py` (a relative path)."""
    data = tmp_path_factory.mktemp("project") / "data"
    data.mkdir()
    (data / "my_tasks.py").write_text(TASK)
    done = _simreel(data, "record", "MyMovablePick-v1", "--import", "my_tasks.py", "-o", "run.h5", "-n", "1",
                    "--max-steps", "8", "--render-backend", "none", "-q")
    assert done.returncode == 0, done.stderr
    return data / "run.h5"


def test_a_custom_task_recording_replays_from_another_folder(recorded, tmp_path):
    """The recording names its task file by its absolute path, so it replays from anywhere on this machine."""
    done = _simreel(tmp_path, "inspect", str(recorded))
    assert f"imports    {recorded.parent / 'my_tasks.py'}" in done.stdout
    done = _simreel(tmp_path, "replay", str(recorded), "-q", "--trust-recorded-imports")
    assert done.returncode == 0, done.stderr
    assert "1 of 1 episode(s) verified (1 exact" in done.stdout


@pytest.fixture
def moved(recorded, tmp_path) -> Path:
    """A copy of the recording's folder in tmp_path/moved, while the recorded task file is gone."""
    moved = tmp_path / "moved"
    shutil.copytree(recorded.parent, moved)
    (recorded.parent / "my_tasks.py").rename(recorded.parent / "my_tasks.py.bak")
    yield moved
    (recorded.parent / "my_tasks.py.bak").rename(recorded.parent / "my_tasks.py")


def test_a_moved_recording_finds_its_task_beside_it_or_is_told_where(recorded, moved, tmp_path):
    """Recording and task moved together: found beside the recording. Task moved elsewhere: one line naming
    what was tried, exit 2; an explicit --import, which wins over the recorded one, makes it replay."""
    done = _simreel(tmp_path, "replay", "moved/run.h5", "-q", "--trust-recorded-imports")
    assert done.returncode == 0, done.stderr
    (tmp_path / "lib").mkdir()
    (moved / "my_tasks.py").rename(tmp_path / "lib" / "my_tasks.py")
    done = _simreel(tmp_path, "replay", "moved/run.h5", "-q", "--trust-recorded-imports")
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        f"simreel replay: error: the recording's --import {recorded.parent}/my_tasks.py is not found here "
        f"(tried {recorded.parent}/my_tasks.py, {moved}/my_tasks.py, module my_tasks on sys.path); pass "
        "--import with where it is now, e.g. --import PATH/TO/my_tasks.py"]
    done = _simreel(tmp_path, "replay", "moved/run.h5", "--import", "lib/my_tasks.py", "-q")
    assert done.returncode == 0, done.stderr


@pytest.mark.slow
@pytest.mark.parametrize("command", [["view", "--geometry", "collision", "--save", "run.rrd"],
                                     ["convert", "run.mcap", "--poses", "-q"]], ids=["view", "convert-poses"])
def test_view_and_convert_poses_take_import(recorded, moved, tmp_path, command):
    """The other commands that rebuild a recording's env, with the task file where the recording does not say."""
    (tmp_path / "lib").mkdir()
    (moved / "my_tasks.py").rename(tmp_path / "lib" / "my_tasks.py")
    name, *rest = command
    done = _simreel(tmp_path, name, "moved/run.h5", *rest)
    assert done.returncode == 2 and "the recording's --import" in done.stderr
    done = _simreel(tmp_path, name, "moved/run.h5", *rest, "--import", "lib/my_tasks.py")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / ("run.rrd" if name == "view" else "run.mcap")).stat().st_size > 1000
