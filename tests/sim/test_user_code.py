"""`simreel.sim.user_code`: importing the user's tasks and policies (``--import``), one-line errors, and a
recording's imports found again from another folder."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from simreel.errors import EnvBuildError, UsageError
from simreel.sim.user_code import found_spec, import_user_code, recorded_spec, resolve_task_imports


def test_import_user_file(tmp_path: Path):
    path = tmp_path / "simreel_test_user_policy.py"
    path.write_text("VALUE = 42\n")
    module = import_user_code(str(path))
    assert module.VALUE == 42
    assert import_user_code(str(path)) is module  # importing twice gives the same module
    assert import_user_code("simreel_test_user_policy") is module  # its folder is now on sys.path


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda d: str(d / "missing.py"), "--import {d}/missing.py: file not found"),
        (lambda d: _write(d / "broken.py", "def f(:\n"), "--import {d}/broken.py: SyntaxError: invalid syntax ("),
        (lambda d: _write(d / "raises.py", "raise RuntimeError('no\\nway')\n"),
         "--import {d}/raises.py: RuntimeError: no way"),
        (lambda d: _write(d / "needs_dep.py", "import simreel_no_such_dependency\n"),
         "--import {d}/needs_dep.py: ModuleNotFoundError: No module named 'simreel_no_such_dependency'"),
        (lambda d: "simreel_no_such_module.sub",
         "--import simreel_no_such_module.sub: no module named 'simreel_no_such_module' on sys.path; "
         "pass a path ending in .py to import a file"),
    ],
)
def test_import_user_code_errors(tmp_path: Path, make, message):
    with pytest.raises(EnvBuildError) as caught:
        import_user_code(make(tmp_path))
    assert str(caught.value).startswith(message.format(d=tmp_path))
    assert "\n" not in str(caught.value)


def _write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


# ------------------------------------------------------------------ a recording's imports, found again


def test_a_recording_stores_a_file_by_its_absolute_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert recorded_spec("tasks/my_tasks.py") == str(tmp_path / "tasks" / "my_tasks.py")
    assert recorded_spec("my_package.tasks") == "my_package.tasks"


def test_a_recorder_stores_only_a_spec_found_now(tmp_path, monkeypatch):
    """A spec found nowhere was stored as it was, and replay then said the file "is not found here" as if it had
    moved; it is refused when the recorder starts, by the rule `import_user_code` applies (a file that is there, a
    module that imports), without importing it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tasks").mkdir()
    (tmp_path / "tasks" / "found_tasks.py").write_text("raise RuntimeError('not imported by the check')\n")
    assert found_spec("tasks/found_tasks.py") == str(tmp_path / "tasks" / "found_tasks.py")
    assert found_spec("simreel.tasks") == "simreel.tasks"
    with pytest.raises(UsageError) as refused:
        found_spec("tasks/lost_tasks.py")
    assert str(refused.value) == (f"imports: tasks/lost_tasks.py: no such file ({tmp_path}/tasks/lost_tasks.py); name "
                                  "the .py file that registers the task")
    with pytest.raises(UsageError) as refused:
        found_spec("simreel_lost_tasks.sub")
    assert str(refused.value) == (f"imports: simreel_lost_tasks.sub: no module of that name on sys.path or in "
                                  f"{tmp_path}; name the module or the .py file that registers the task")


@pytest.fixture
def layout(tmp_path, monkeypatch):
    """rec/run.h5 beside rec/my_tasks.py, a second task file in lib/, the current folder elsewhere/."""
    for folder in ("rec", "lib", "elsewhere"):
        (tmp_path / folder).mkdir()
    (tmp_path / "rec" / "run.h5").write_bytes(b"")
    (tmp_path / "rec" / "my_tasks.py").write_text("")
    (tmp_path / "lib" / "other_tasks.py").write_text("")
    monkeypatch.chdir(tmp_path / "elsewhere")
    return tmp_path


@pytest.mark.parametrize(
    ("recorded", "found"),
    [
        ("{t}/lib/other_tasks.py", "{t}/lib/other_tasks.py"),  # an absolute path that is still there
        ("{t}/gone/my_tasks.py", "{t}/rec/my_tasks.py"),  # moved along with the recording
        ("my_tasks.py", "{t}/rec/my_tasks.py"),  # recorded relative, in the recording's folder
        ("../lib/other_tasks.py", "{t}/lib/other_tasks.py"),  # recorded relative: from the recording's folder
    ],
    ids=["absolute", "beside-the-recording", "old-relative", "old-relative-up"],
)
def test_recorded_files_are_found_from_another_folder(layout, recorded, found):
    spec = recorded.format(t=layout)
    assert resolve_task_imports([spec], recording=layout / "rec" / "run.h5", trust=True) == [found.format(t=layout)]


def test_a_recorded_file_found_nowhere_may_be_a_module_on_sys_path(layout, monkeypatch):
    monkeypatch.syspath_prepend(str(layout / "lib"))
    assert resolve_task_imports([f"{layout}/gone/other_tasks.py"], recording=layout / "rec" / "run.h5",
                                trust=True) == ["other_tasks"]


def test_a_recorded_module_is_found_beside_the_recording(layout, monkeypatch):
    monkeypatch.setattr(sys, "path", list(sys.path))
    assert resolve_task_imports(["my_tasks"], recording=layout / "rec" / "run.h5", trust=True) == ["my_tasks"]
    assert str(layout / "rec") in sys.path  # so that import_user_code("my_tasks") finds it


def test_an_explicit_import_wins_over_the_recorded_ones(layout):
    """Even where the recorded file exists: the user said which code registers the task."""
    recorded = [str(layout / "rec" / "my_tasks.py"), "no_such_module_xyz"]
    assert resolve_task_imports(recorded, explicit=["../lib/other_tasks.py"], recording=layout / "rec" / "run.h5") == [
        str(layout / "lib" / "other_tasks.py")]


def test_a_recorded_import_found_nowhere_names_every_place_tried(layout):
    with pytest.raises(EnvBuildError) as caught:
        resolve_task_imports([f"{layout}/gone/lost_tasks.py"], recording=layout / "rec" / "run.h5", trust=True)
    assert str(caught.value) == (
        f"the recording's --import {layout}/gone/lost_tasks.py is not found here (tried {layout}/gone/lost_tasks.py, "
        f"{layout}/rec/lost_tasks.py, module lost_tasks on sys.path); pass --import with where it is now, e.g. "
        "--import PATH/TO/lost_tasks.py")
    with pytest.raises(EnvBuildError) as caught:
        resolve_task_imports(["lost_tasks_module"], recording=layout / "rec" / "run.h5", trust=True)
    assert str(caught.value) == (
        f"the recording's --import lost_tasks_module is not found here (tried module lost_tasks_module on sys.path "
        f"and in {layout}/elsewhere, {layout}/rec/lost_tasks_module.py); pass --import with where it is now, e.g. "
        "--import PATH/TO/lost_tasks_module.py")


def test_a_recordings_code_is_imported_only_with_the_users_word(layout, monkeypatch):
    """A recording is data that may come from anywhere: the code it names (a file, or a module beside it or in the
    current folder, where anybody's dataset can put one) was imported by every command that rebuilt its env. Now
    only with an --import, --trust-recorded-imports or SIMREEL_TRUST_RECORDED_IMPORTS=1; otherwise one line."""
    monkeypatch.delenv("SIMREEL_TRUST_RECORDED_IMPORTS", raising=False)
    recording = layout / "rec" / "run.h5"
    (layout / "elsewhere" / "cwd_tasks.py").write_text("")
    for recorded in ([str(layout / "rec" / "my_tasks.py")], ["my_tasks"], ["cwd_tasks"],
                     [f"{layout}/gone/my_tasks.py"]):
        with pytest.raises(UsageError) as refused:
            resolve_task_imports(recorded, recording=recording)
        assert str(refused.value) == (
            f"{recording}: the recording asks to import {recorded[0]}, code that came with the data and would run as "
            f"you; pass --import with the task code you trust (e.g. --import {recorded[0]}), or "
            "--trust-recorded-imports (or SIMREEL_TRUST_RECORDED_IMPORTS=1) if you trust where it came from")
    assert resolve_task_imports(["my_tasks"], recording=recording, trust=True) == ["my_tasks"]
    monkeypatch.setenv("SIMREEL_TRUST_RECORDED_IMPORTS", "1")
    assert resolve_task_imports(["cwd_tasks"], recording=recording) == ["cwd_tasks"]
    monkeypatch.setenv("SIMREEL_TRUST_RECORDED_IMPORTS", "0")
    with pytest.raises(UsageError):
        resolve_task_imports(["cwd_tasks"], recording=recording)


def test_a_module_installed_in_this_python_is_imported_as_installed_code_is(layout, monkeypatch):
    """Installing a package was the user's word; a module of the same name planted beside the recording is not."""
    monkeypatch.delenv("SIMREEL_TRUST_RECORDED_IMPORTS", raising=False)
    recording = layout / "rec" / "run.h5"
    assert resolve_task_imports(["simreel.tasks", "json"], recording=recording) == ["simreel.tasks", "json"]
    monkeypatch.syspath_prepend(str(layout / "lib"))  # as PYTHONPATH or an installed package would put it
    assert resolve_task_imports(["other_tasks"], recording=recording) == ["other_tasks"]
    monkeypatch.syspath_prepend(str(layout / "rec"))  # the recording's folder on sys.path does not make it installed
    with pytest.raises(UsageError, match="asks to import my_tasks,"):
        resolve_task_imports(["my_tasks"], recording=recording)


def test_a_rebuilt_env_imports_only_code_the_user_gave_their_word_for(tmp_path, monkeypatch):
    """The last guard, for Python callers that pass a recording's metadata as read (`env_from_meta`)."""
    from simreel.model.meta import RecordingMeta
    from simreel.sim.rebuild import env_from_meta

    monkeypatch.delenv("SIMREEL_TRUST_RECORDED_IMPORTS", raising=False)
    planted = tmp_path / "planted_tasks.py"
    planted.write_text(f"open({str(tmp_path / 'ran')!r}, 'w').close()\n")
    meta = RecordingMeta(env_id="PickCube-v1", imports=[str(planted)])
    with pytest.raises(UsageError, match=f"the recording asks to import {planted}, code that came with the data"):
        env_from_meta(meta)
    assert not (tmp_path / "ran").exists()


def test_a_relative_import_is_kept_from_the_folder_it_was_given_in(tmp_path):
    assert recorded_spec("tasks/noop.py", base=tmp_path) == str(tmp_path / "tasks" / "noop.py")
    assert recorded_spec("/abs/noop.py", base=tmp_path) == "/abs/noop.py"
    assert recorded_spec("my_tasks.mod", base=tmp_path) == "my_tasks.mod"  # a module is found by its name


BUGGY_TASK = '''
import os
from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
from mani_skill.utils.registration import register_env

@register_env("SimreelTestBuggyEvaluate-v1", max_episode_steps=50)
class BuggyEvaluate(PickCubeEnv):
    def evaluate(self):
        if os.environ.get("SIMREEL_TEST_BUG") and int(self.elapsed_steps[0]) >= 3:
            raise ZeroDivisionError("a bug of the task's author")
        return super().evaluate()

    def _initialize_episode(self, env_idx, options):
        super()._initialize_episode(env_idx, options)
        if os.environ.get("SIMREEL_TEST_RESET_BUG"):
            raise KeyError("a bug in reset")
'''


def test_an_error_raised_in_the_users_task_code_is_one_line_naming_its_line_not_an_internal_error(tmp_path):
    """A task's own step code raising (here its `evaluate`, from step 3) was `internal error ... please report it`,
    exit 3, in record, audit and replay, and stopped a whole dataset run; now one line naming the task's file and
    line, exit 2, and in a dataset run that episode's verdict is `error` while the others go on."""
    import os
    import subprocess

    from support.processes import simreel_command

    task = tmp_path / "buggy_tasks.py"
    task.write_text(BUGGY_TASK)
    env_id, line = "SimreelTestBuggyEvaluate-v1", 10
    said = (f"the task's own code raised ZeroDivisionError: a bug of the task's author (buggy_tasks.py, line {line}, "
            "in evaluate); fix the task")
    (tmp_path / "ds").mkdir()

    def run(*args: str, bug: bool = True) -> subprocess.CompletedProcess:
        env = {**os.environ, "SIMREEL_TEST_BUG": "1"} if bug else os.environ
        return subprocess.run(simreel_command(*args), capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)

    clean = run("record", env_id, "--import", str(task), "-o", "ds/a.h5", "-n", "2", "--max-steps", "6", "-q", bug=False)
    assert clean.returncode == 0, clean.stderr
    for args in (("record", env_id, "--import", str(task), "-o", "b.h5", "--max-steps", "6", "-q"),
                 ("audit", env_id, "--import", str(task)),
                 ("replay", "ds/a.h5", "--trust-recorded-imports", "-q")):
        done = run(*args)
        assert (done.returncode, done.stderr.splitlines()[-1]) == (2, f"simreel {args[0]}: error: {said}"), args
    dataset = run("replay", "ds", "--import", str(task), "-q")
    assert dataset.returncode == 2, dataset.stderr
    assert dataset.stdout.count(f"error             {said}") == 2
    assert "2 could not be replayed" in dataset.stdout
    # raised while the env is built (ManiSkill resets it then): was "could not build the env: KeyError: ..."
    done = subprocess.run(simreel_command("record", env_id, "--import", str(task), "-o", "c.h5", "-q"), cwd=tmp_path,
                          capture_output=True, text=True, timeout=300, env={**os.environ, "SIMREEL_TEST_RESET_BUG": "1"})
    assert (done.returncode, done.stderr.splitlines()[-1]) == (
        2, "simreel record: error: the task's own code raised KeyError: 'a bug in reset' (buggy_tasks.py, line 16, in "
           "_initialize_episode); fix the task")
