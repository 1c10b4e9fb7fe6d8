"""The architecture, checked: the core's top level holds only the package's constants, its errors and its entry
point; the core's packages are layers that import only downwards; the rooms (recorders, replay, viewers) import the
core and never each other; the core imports no room but through the CLI; importing simreel and building the CLI
parser load no simulator or viewer; and the tests mirror the package."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
ROOMS = {"recorders": "simreel.recorders", "replay": "simreel.replay", "training": "simreel.training",
         "viewers": "simreel.viewers"}
PACKAGE_DIRS = {"simreel": REPO / "simreel", **{room: REPO / room for room in ROOMS}}
CORE_TOP = {"__init__.py", "__main__.py", "errors.py"}
"""The core's top level: the version and format constants, the one exception hierarchy, `python -m simreel`."""

LAYERS: dict[str, int] = {
    "simreel": 0, "simreel.errors": 0,
    "simreel.options": 1,
    "simreel.model": 2,
    "simreel.io": 3,
    "simreel.formats": 4, "simreel.verdicts": 4, "simreel.authoring": 4,
    "simreel.tasks": 5,
    "simreel.sim": 6,
    "simreel.datasets": 7,
    **dict.fromkeys(ROOMS.values(), 8),
    "simreel.cli": 9, "simreel.__main__": 10,
}
"""The layers of the package, lowest first: a module imports only from its own unit or from a lower layer. Units
of one layer never import each other (formats, verdicts and authoring know nothing of each other)."""

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


def test_the_core_top_level_holds_only_constants_errors_and_the_entry_point():
    assert {p.name for p in (REPO / "simreel").glob("*.py")} == CORE_TOP


def _module_name(path: Path) -> str:
    """The dotted name `path` imports as (the rooms live at the repository's top as simreel.<room>)."""
    for package, folder in PACKAGE_DIRS.items():
        if folder in path.parents:
            parts = path.relative_to(folder).with_suffix("").parts
            prefix = "simreel" if package == "simreel" else ROOMS[package]
            return ".".join((prefix, *(p for p in parts if p != "__init__")))
    raise ValueError(path)


def _unit(module: str) -> str:
    """The layer unit `module` belongs to: the longest key of `LAYERS` it is or lies inside."""
    return max((u for u in LAYERS if module == u or module.startswith(u + ".")), key=len)


def _every_module() -> list[Path]:
    return sorted(p for folder in PACKAGE_DIRS.values() for p in folder.rglob("*.py"))


def test_every_package_of_the_core_has_a_layer():
    units = {_unit(_module_name(p)) for p in _every_module()}
    tops = {f"simreel.{p.name}" for p in (REPO / "simreel").iterdir() if (p / "__init__.py").is_file()}
    assert tops <= set(LAYERS), f"core packages without a layer: {sorted(tops - set(LAYERS))}"
    assert units <= set(LAYERS)


def test_the_layers_import_only_downwards():
    wrong = []
    for path in _every_module():
        unit = _unit(_module_name(path))
        for imported in sorted(m for m in _imports(path) if m == "simreel" or m.startswith("simreel.")):
            other = _unit(imported)
            if other != unit and LAYERS[other] >= LAYERS[unit]:
                wrong.append(f"{path.relative_to(REPO)} ({unit}, layer {LAYERS[unit]}) imports {imported} "
                             f"(layer {LAYERS[other]})")
    assert not wrong, "imports against the layer order:\n" + "\n".join(wrong)


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
        "import simreel.viewers, simreel.replay, simreel.training, simreel.formats, simreel.sim.make, simreel.sim.render_device, "
        "simreel.sim.norender, simreel.authoring.custom_state, simreel.authoring.heterogeneous, simreel.datasets.dataset, "
        "simreel.verdicts.compare, simreel.model.episode; "
        "print(json.dumps([n for n in ('rerun', 'mani_skill', 'sapien', 'torch') if n in sys.modules]))"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert json.loads(done.stdout) == []


PUBLIC_API = {
    "simreel": ["__version__", "FORMAT_VERSION"],
    "simreel.errors": ["SimreelError", "UsageError"],
    "simreel.recorders": ["RecordWrapper", "RecordOptions", "stopping_signals"],
    "simreel.replay": ["verify_recording", "read_verdicts", "audit_task", "ReplayOptions", "ReplayRun", "MODES",
                       "EpisodeReplayer", "AuditOptions"],
    "simreel.replay.convert.convert": ["convert_recording", "ConvertOptions"],
    "simreel.training": ["RecordingDataset", "SampleOptions", "EpisodeChoice", "FeatureStats", "compute_stats"],
    "simreel.viewers": ["build_session", "ViewOptions"],
    "simreel.formats": ["open_reader", "open_writer", "EpisodeReader", "EpisodeWriter", "StepBlock"],
    "simreel.model": [],
    "simreel.model.meta": ["RecordingMeta", "EpisodeMeta"],
    "simreel.model.lineage": ["SceneChain", "ScenePlace", "EpisodeOrigin", "EpisodeProvenance", "EpisodeVerification"],
    "simreel.model.episode": ["Episode"],
    "simreel.sim.make": ["make_env", "EnvConfig"],
    "simreel.datasets.copy": ["recover"],
    "simreel.authoring.custom_state": ["CustomStateMixin"],
    "simreel.authoring.heterogeneous": ["build_heterogeneous_actor", "build_heterogeneous_articulation"],
    "simreel.tasks": [],
}
"""The documented Python API (docs/api.md lists it): each name at its one stable home."""


@pytest.mark.parametrize("module", sorted(PUBLIC_API))
def test_the_documented_api_imports_from_its_home(module):
    imported = __import__(module, fromlist=["_"])
    missing = [name for name in PUBLIC_API[module] if not hasattr(imported, name)]
    assert not missing, f"{module} lacks {missing}"


def test_import_simreel_changes_nothing_outside_it():
    script = ("import os, sys; before = dict(os.environ); names = set(sys.modules); import simreel; "
              "print(dict(os.environ) == before, sorted(set(sys.modules) - names))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.split(maxsplit=1) == ["True", "['simreel']\n"]


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
