"""`simreel.sim.user_code`: importing the user's tasks and policies (``--import``), and one-line errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from simreel.errors import EnvBuildError
from simreel.sim.user_code import import_user_code


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
