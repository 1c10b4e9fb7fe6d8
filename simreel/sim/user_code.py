"""Import the user's own code (custom tasks, policies) for the CLI's ``--import``, and mani_skill whole and
quietly; find a recording's imports again wherever it is replayed.

A recording stores its ``--import`` specs (`recorded_spec`: a file by its absolute path, a module by its name).
Rebuilding its env imports them again (`resolve_task_imports`) only with the user's word, since a recording is data
that may come from anywhere and its code runs as the user: an ``--import`` given now wins; a recorded module
installed in this Python (found on ``sys.path``, not in the current folder nor beside the recording) is imported
as installed code is; any other recorded spec needs ``--trust-recorded-imports`` (or ``SIMREEL_TRUST_RECORDED_IMPORTS=1``),
and without it the command stops with one line naming what the recording asks to import. Trusted, each recorded
spec is looked for at its absolute path, beside the recording, in the current folder and as a module, and a spec
found nowhere is one error line naming every place tried.

mani_skill (~3 s to import) and sapien are imported inside the functions here, never at module level.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.machinery
import importlib.util
import os
import sys
import traceback
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from simreel.errors import EnvBuildError, TaskCodeError, UsageError
from simreel.io.durable import deferred_signals
from simreel.io.paths import SYMLINK_LOOP, is_symlink_loop, real_path
from simreel.options.checks import flag, text_tuple
from simreel.options.declare import Option
from simreel.sim.render_device import configure_vulkan

__all__ = ["import_specs", "found_spec", "import_user_code", "imported_user_code", "import_mani_skill", "native_import",
           "recorded_spec", "resolve_task_imports", "refuse_untrusted_imports", "refuse_unvetted_imports",
           "trusts_recorded_imports",
           "task_code_error", "IMPORTS", "TRUST_IMPORTS", "TRUST_VARIABLE"]

_IMPORTED: dict[str, str] = {}
"""Every spec `import_user_code` imported in this process, in order, and the name of the module it gave."""

_ADDED_TO_SYS_PATH: set[str] = set()
"""The folders simreel put on ``sys.path`` (an imported file's, a recording's): not where installed modules are."""

_VETTED: set[str] = set()
"""The specs `resolve_task_imports` returned in this process: the user's ``--import``, or recorded ones the user
trusts; `refuse_unvetted_imports` lets a rebuilt env import these."""


def import_mani_skill() -> None:
    """Import mani_skill, registering its tasks, whole and quietly (`native_import`)."""
    with native_import():
        import mani_skill.envs  # noqa: F401


@contextlib.contextmanager
def native_import() -> Iterator[None]:
    """Where simreel imports mani_skill, sapien and torch: whole, and quietly.

    Whole: SIGINT and SIGTERM are held until the import is done (`deferred_signals`), then handled. A
    KeyboardInterrupt raised inside it aborts the process when it lands in a native module's initialisation
    (torch's), turns into an ImportError in another's (sapien's), and is swallowed by trimesh, which catches every
    exception around its optional imports and leaves stand-ins behind: the command then went on, or failed later
    on a half-made module. Only signals a Python handler takes are held: one whose default ends the process (a
    replay's worker process told to stop, a script without a SIGTERM handler) ends it at once, not seconds later.

    Quietly: sapien warns that it falls back to its bundled libvulkan when the system has none; that is expected
    and fine, so the warning is hidden."""
    with deferred_signals(handled_only=True), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*libvulkan.*", category=UserWarning)
        yield


def import_user_code(spec: str) -> ModuleType:
    """Import a dotted module or a ``.py`` file, for the CLI's ``--import``: custom tasks and policies.

    A ``.py`` path is loaded as a module named after the file (its folder goes first on ``sys.path``, as when
    Python runs a script, so it can import its neighbours). A dotted name is imported normally, with the current
    folder appended to ``sys.path`` so ``--import mytasks`` finds ``./mytasks.py``. Vulkan is configured and mani_skill
    imported first (`native_import`), because user code usually imports mani_skill; the user's own code then imports
    as it would anywhere, signals as usual (it may run anything, for any time). Any failure becomes one-line
    `EnvBuildError`.
    """
    configure_vulkan()
    import_mani_skill()
    module = _import_user_code(spec)
    _IMPORTED.setdefault(spec, module.__name__)
    return module


def imported_user_code() -> dict[str, str]:
    """The user's code this process imported (`import_user_code` spec -> module name), simreel's own modules
    left out; error messages name it (an env id none of it registers)."""
    return {spec: name for spec, name in _IMPORTED.items() if name != "simreel" and not name.startswith("simreel.")}


def task_code_error(exc: BaseException) -> TaskCodeError | None:
    """`exc` as an error of the user's own code, where its traceback runs through a file this process imported with
    `import_user_code` (a task's step, evaluate or reward raising): a bug for the task's author, said in one line that
    names where (exit 2), not an internal error of simreel's. None where no frame of it is in that code."""
    files = _user_files()
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if f.filename in files] if files else []
    if not frames:
        return None
    last = frames[-1]
    message = " ".join(str(exc).split())
    return TaskCodeError(f"the task's own code raised {type(exc).__name__}: {message} ({Path(last.filename).name}, "
                         f"line {last.lineno}, in {last.name}); fix the task")


def _user_files() -> set[str]:
    """The files of the modules `imported_user_code` names, as tracebacks spell them."""
    files = (getattr(sys.modules.get(name), "__file__", None) for name in imported_user_code().values())
    return {f for f in files if f}


def import_specs(imports: Any) -> tuple[str, ...]:
    """The `imports` option of the recorder or of replay as a tuple of ``--import`` specs: one string is one spec (not
    one spec per character); anything but strings is `UsageError`."""
    return text_tuple("imports", imports, 'the .py files or modules that register the task, as a tuple of strings, '
                      'e.g. ("my_tasks.py",)')


IMPORTS = Option(
    help="import user code (a module or a .py file) that registers tasks or policies; repeatable. Given to a command "
         "that reads a recording, it is imported instead of the code the recording names",
    flags=("--import",), metavar="MODULE_OR_FILE", action="append", cli_default=[], from_cli=tuple,
    check=lambda name, value: tuple(recorded_spec(spec) for spec in import_specs(value)))
"""``--import``, declared once for every command that takes it; its check keeps a file by its absolute path (a
resumed run, or a worker, may work in another folder)."""


TRUST_VARIABLE = "SIMREEL_TRUST_RECORDED_IMPORTS"
"""Set to 1: every command trusts the code recordings and reports name, as ``--trust-recorded-imports`` does."""

TRUST_IMPORTS = Option(
    help="import the task code a recording (or a resumed report) names, without an --import of your own: only for "
         f"data you trust, since that code runs as you (or set {TRUST_VARIABLE}=1). Modules installed in this Python "
         "are imported without it",
    flags=("--trust-recorded-imports",), action="store_true", check=flag())
"""``--trust-recorded-imports``, declared once for every command that rebuilds a recording's env."""


def trusts_recorded_imports(given: bool = False) -> bool:
    """Whether the code a recording names may be imported: `given` (``--trust-recorded-imports``), or
    `TRUST_VARIABLE` set to anything but empty or 0."""
    return bool(given) or os.environ.get(TRUST_VARIABLE, "").strip() not in ("", "0")


def refuse_untrusted_imports(recorded: Sequence[str], *, explicit: Sequence[str] = (), trust: bool = False,
                             source: str | Path | None = None, what: str = "recording") -> None:
    """`UsageError` (one line, exit 2) where `recorded` (the specs a recording or a report at `source` names) would
    be imported without the user's word: no ``--import`` given now (`explicit`), no trust given
    (`trusts_recorded_imports`), and a spec that is not a module installed in this Python (`_installed_module`)."""
    if explicit or trusts_recorded_imports(trust):
        return
    folder = Path(source).absolute().parent if source is not None else None
    asked = [spec for spec in recorded if not _installed_module(spec, folder)]
    if asked:
        where = f"{source}: the {what}" if source is not None else f"the {what}"
        raise UsageError(f"{where} asks to import {', '.join(asked)}, code that came with the data and would run as "
                         f"you; pass --import with the task code you trust (e.g. --import {asked[0]}), or "
                         f"--trust-recorded-imports (or {TRUST_VARIABLE}=1) if you trust where it came from")


def _installed_module(spec: str, folder: Path | None) -> bool:
    """Whether `spec` names a module installed in this Python: found on ``sys.path`` leaving out the current folder
    and `folder` (the recording's), where anybody's data can put a file of that name."""
    if _is_path(spec) or not all(part.isidentifier() for part in spec.split(".")):
        return False
    top = spec.partition(".")[0]
    if top in sys.builtin_module_names:
        return True
    untrusted = {os.path.realpath(p) for p in [os.getcwd(), *_ADDED_TO_SYS_PATH, *([folder] if folder else [])]}
    installed = [p for p in sys.path if p and os.path.realpath(p) not in untrusted]
    for finder in sys.meta_path:  # the path finder, and those installed packages bring (an editable install's)
        if finder is importlib.machinery.PathFinder:
            found = finder.find_spec(top, installed)
        else:
            found = getattr(finder, "find_spec", lambda *_: None)(top, None)
        if found is not None:
            return True
    return False


def recorded_spec(spec: str, *, base: str | Path | None = None) -> str:
    """An ``--import`` spec as a recording stores it: a file by its absolute path (a relative path would name
    the file only from the folder it was recorded in), a module by its name. `base`: the folder a relative path
    was given in (default: the current one), e.g. the working folder of the run a report resumes."""
    if not _is_path(spec):
        return spec
    return str(real_path(Path(base or os.getcwd()) / Path(spec).expanduser()))


def found_spec(spec: str) -> str:
    """`recorded_spec` of an ``--import`` spec that a recorder stores now: it must name a .py file that is there or a
    module that can be imported (the same rule `import_user_code` applies, without importing it again), else
    `UsageError`. A spec that resolves nowhere when it is recorded could never be imported by a replay."""
    stored = recorded_spec(spec)
    if _is_path(spec) and is_symlink_loop(stored):
        raise UsageError(f"imports: {spec}: {SYMLINK_LOOP}")
    if _is_path(spec) and not os.path.isfile(stored):
        raise UsageError(f"imports: {spec}: no such file ({stored}); name the .py file that registers the task")
    if not _is_path(spec) and not _module_found(spec):
        raise UsageError(f"imports: {spec}: no module of that name on sys.path or in {os.getcwd()}; name the module "
                         "or the .py file that registers the task")
    return stored


def resolve_task_imports(recorded: Sequence[str], *, explicit: Sequence[str] = (),
                         recording: str | Path | None = None, trust: bool = False) -> list[str]:
    """The ``--import`` specs that register a recording's task here, each importable as it is.

    `explicit` (``--import`` given now) wins: when there is any, the recorded specs are not used. Otherwise the
    recorded specs are used only with the user's word (`refuse_untrusted_imports`: `trust`, or installed modules),
    and each is found: a file at its recorded path if absolute, else beside `recording` (the recording's
    path), under its own name beside `recording`, in the current folder, or as the module named after it; a
    module on ``sys.path``, in the current folder or beside `recording`. Raises `EnvBuildError` for a spec found
    nowhere, naming every place tried and the ``--import`` that fixes it.
    """
    if explicit:
        found = [recorded_spec(spec) for spec in explicit]
    else:
        refuse_untrusted_imports(recorded, trust=trust, source=recording)
        folder = Path(recording).absolute().parent if recording is not None else None
        found = [_find_file(spec, folder) if _is_path(spec) else _find_module(spec, folder) for spec in recorded]
    _VETTED.update(found)
    return found


def refuse_unvetted_imports(specs: Sequence[str]) -> None:
    """`UsageError` where a recording's env would be rebuilt importing a spec the user gave no word for: not found
    by `resolve_task_imports` in this process (the user's ``--import``, or trusted recorded imports), not a module
    installed in this Python, and `TRUST_VARIABLE` not set. The last guard of every rebuilt env
    (`simreel.sim.rebuild.import_task_code`), for a caller that passes a recording's metadata as it was read."""
    refuse_untrusted_imports([spec for spec in specs if spec not in _VETTED])


def _is_path(spec: str) -> bool:
    return spec.endswith(".py") or os.sep in spec or (os.altsep is not None and os.altsep in spec)


def _find_file(spec: str, folder: Path | None) -> str:
    path = Path(spec).expanduser()
    beside = [] if folder is None else [folder / path.name]
    if path.is_absolute():
        candidates = [path, *beside]
    else:  # recorded before paths were stored absolute: relative to the folder the recording was made in
        candidates = [*([] if folder is None else [folder / path]), *beside, Path.cwd() / path]
    tried = list(dict.fromkeys(os.path.normpath(c) for c in candidates))
    found = next((c for c in tried if os.path.isfile(c)), None)
    if found is not None:
        return found
    module = path.stem if path.stem.isidentifier() else None
    if module is not None and _module_found(module):
        return module
    raise _not_found(spec, tried + ([f"module {module} on sys.path"] if module else []), path.name)


def _find_module(spec: str, folder: Path | None) -> str:
    if _module_found(spec):
        return spec
    top = spec.partition(".")[0]
    beside = [folder / f"{top}.py", folder / top / "__init__.py"] if folder is not None else []
    if any(p.is_file() for p in beside):
        _add_to_sys_path(str(folder), first=False)
        return spec
    raise _not_found(spec, [f"module {spec} on sys.path and in {os.getcwd()}", *map(str, beside[:1])],
                     f"{top}.py")


def _not_found(spec: str, tried: list[str], name: str) -> EnvBuildError:
    return EnvBuildError(f"the recording's --import {spec} is not found here (tried {', '.join(tried)}); pass "
                         f"--import with where it is now, e.g. --import PATH/TO/{name}")


def _module_found(name: str) -> bool:
    """Whether `name` can be imported (the current folder included, as `import_user_code` looks)."""
    _cwd_on_sys_path()
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:
        return False
    except Exception:  # noqa: BLE001 - a parent package that fails to import: import_user_code says how
        return True


def _add_to_sys_path(folder: str, *, first: bool) -> None:
    _ADDED_TO_SYS_PATH.add(folder)
    if folder in sys.path:
        return
    if first:
        sys.path.insert(0, folder)
    else:
        sys.path.append(folder)


def _cwd_on_sys_path() -> None:
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.append(os.getcwd())


def _import_user_code(spec: str) -> ModuleType:
    try:
        if _is_path(spec):
            return _import_file(Path(spec))
        _cwd_on_sys_path()
        return importlib.import_module(spec)
    except EnvBuildError:
        raise
    except ModuleNotFoundError as exc:
        if exc.name is not None and (spec == exc.name or spec.startswith(exc.name + ".")):
            raise EnvBuildError(
                f"--import {spec}: no module named {exc.name!r} on sys.path; pass a path ending in .py to import a file"
            ) from exc
        raise EnvBuildError(f"--import {spec}: {type(exc).__name__}: {exc}") from exc
    except (Exception, SystemExit) as exc:
        message = " ".join(str(exc).split())
        raise EnvBuildError(f"--import {spec}: {type(exc).__name__}: {message}") from exc


def _import_file(path: Path) -> ModuleType:
    path = real_path(path.expanduser())
    if not path.is_file():
        raise EnvBuildError(f"--import {path}: {SYMLINK_LOOP if is_symlink_loop(path) else 'file not found'}")
    name = path.stem if path.stem.isidentifier() else "simreel_user_module"
    existing = sys.modules.get(name)
    if existing is not None:
        if getattr(existing, "__file__", None) and Path(existing.__file__).resolve() == path:
            return existing
        name = f"simreel_user_{abs(hash(str(path))):x}"
    module_spec = importlib.util.spec_from_file_location(name, path)
    if module_spec is None or module_spec.loader is None:
        raise EnvBuildError(f"--import {path}: cannot be imported as a Python module")
    _add_to_sys_path(str(path.parent), first=True)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    try:
        module_spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
