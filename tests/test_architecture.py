"""The architecture, checked: the core's top level holds only the data model; the rooms (recorders, replay,
viewers) import the core and never each other; the core imports no room but through the CLI; importing simreel
and building the CLI parser load no simulator or viewer; and the tests mirror the package."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
ROOMS = {"recorders": "simreel.recorders", "replay": "simreel.replay", "viewers": "simreel.viewers"}
PACKAGE_DIRS = {"simreel": REPO / "simreel", **{room: REPO / room for room in ROOMS}}
CORE_TOP = {"__init__.py", "__main__.py", "errors.py", "episode.py", "state_tree.py", "compare.py", "divergence.py",
            "scene_history.py", "option_checks.py"}
"""The data model and what both the replay room and the viewer read from it: comparisons and divergence explanations;
the checks of the options every room takes from Python."""


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at module level or inside functions."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def _room_of(module: str) -> str | None:
    return next((room for room, name in ROOMS.items() if module == name or module.startswith(name + ".")), None)


def test_the_core_top_level_holds_only_the_data_model():
    assert {p.name for p in (REPO / "simreel").glob("*.py")} == CORE_TOP


@pytest.mark.parametrize("room", sorted(ROOMS))
def test_a_room_imports_the_core_and_never_another_room(room):
    for path in sorted((REPO / room).rglob("*.py")):
        others = {m for m in _imports(path) if _room_of(m) not in (None, room)}
        assert not others, f"{path.relative_to(REPO)} imports {sorted(others)}"


def test_the_core_imports_a_room_only_in_the_cli():
    for path in sorted((REPO / "simreel").rglob("*.py")):
        if "cli" in path.relative_to(REPO / "simreel").parts:
            continue
        rooms = {m for m in _imports(path) if _room_of(m) is not None}
        assert not rooms, f"{path.relative_to(REPO)} imports {sorted(rooms)}"


def test_import_simreel_and_the_cli_parser_load_no_simulator_or_viewer():
    script = (
        "import json, sys, simreel, simreel.cli.main as m; m.build_parser(); "
        "import simreel.viewers, simreel.replay, simreel.formats, simreel.sim.make, simreel.sim.render_device, "
        "simreel.sim.norender, simreel.custom_state, simreel.heterogeneous; "
        "print(json.dumps([n for n in ('rerun', 'mani_skill', 'sapien', 'torch') if n in sys.modules]))"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert json.loads(done.stdout) == []


def test_the_documented_import_paths_of_the_authoring_helpers_work():
    import simreel.custom_state
    import simreel.heterogeneous
    from simreel.authoring import custom_state, heterogeneous
    from simreel.custom_state import CustomStateMixin

    assert simreel.custom_state is custom_state and simreel.heterogeneous is heterogeneous
    assert CustomStateMixin is custom_state.CustomStateMixin


# ------------------------------------------------------------------------------------ tests mirror the package
CROSS_CUTTING = {"test_architecture.py", "test_readme.py"}
"""Test files about the whole project rather than one module."""


def _package_dir(test_dir: Path) -> Path:
    """The package a test folder mirrors: tests/ → simreel/, tests/sim → simreel/sim, tests/replay → replay/."""
    parts = test_dir.relative_to(TESTS).parts
    if parts and parts[0] in ROOMS:
        return REPO.joinpath(*parts)
    return REPO.joinpath("simreel", *parts)


def _names_in(package: Path) -> set[str]:
    """Modules and subpackages of a package, and the package itself (its __init__)."""
    names = {p.stem for p in package.glob("*.py") if p.stem != "__init__"}
    names |= {p.name for p in package.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    return names | {package.name}


def test_every_test_file_is_found_by_the_path_of_what_it_tests():
    """tests/<path>/test_<name>[_<aspect>].py tests <package>/<path>/<name>: a module, a subpackage or the
    package itself; tests/support/ holds helpers."""
    wrong = []
    for path in sorted(TESTS.rglob("test_*.py")):
        if "support" in path.relative_to(TESTS).parts or (path.parent == TESTS and path.name in CROSS_CUTTING):
            continue
        package = _package_dir(path.parent)
        stem = path.stem[len("test_"):]
        if not package.is_dir() or not any(stem == n or stem.startswith(n + "_") for n in _names_in(package)):
            wrong.append(str(path.relative_to(REPO)))
    assert not wrong, f"test files that name no module of the package their folder mirrors: {wrong}"
