"""Every code block of the README runs, so the README cannot promise what fails.

The blocks run in order, in one scratch folder, as a user with the venv activated would run them (its
``bin/`` first on PATH, no Vulkan variables set: simreel finds its driver itself). What each block is says its
fence and an optional HTML comment on the line before it:

- ```` ```bash ````: shell commands, run with ``bash -e``; every command must succeed.
- ```` ```python ````: run with the venv's Python; ``<!-- file: NAME.py -->`` before it writes it to NAME.py
  instead (a module the later blocks import).
- ```` ```console ````: a transcript. ``$ command`` lines run; the lines after each are its expected output,
  where a line ``...`` stands for any lines and ``...`` inside a line for any text; ``$ echo $?`` checks
  the exit status of the command before it.
- ```` ```text ````: not code (layouts, trees); not run.
- ``<!-- test: slow -->``: runs only with ``-m slow`` (`make test-all`); ``<!-- test: repo -->``: runs in the
  repository root, not the scratch folder; ``<!-- test: skip REASON -->``: not run, for the reason given.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
LANGUAGES = ("bash", "python", "console", "text")
_VULKAN_VARS = ("VK_ICD_FILENAMES", "VK_DRIVER_FILES", "VK_ADD_DRIVER_FILES")
_FENCE = re.compile(r"^```(\w*)\s*$")
_DIRECTIVE = re.compile(r"^<!--\s*(test|file):\s*(.*?)\s*-->$")


@dataclass(frozen=True)
class Block:
    line: int
    language: str
    body: str
    file: str | None = None
    slow: bool = False
    repo: bool = False
    skip: str | None = None

    @property
    def id(self) -> str:
        return f"README.md:{self.line}:{self.language}"


def _directives(lines: list[str], fence: int) -> dict[str, str]:
    """The directive comments on the lines just above the fence at index `fence`."""
    found: dict[str, str] = {}
    k = fence - 1
    while k >= 0 and (m := _DIRECTIVE.match(lines[k].strip())):
        found[m.group(1)] = m.group(2)
        k -= 1
    return found


def read_blocks(text: str) -> list[Block]:
    lines = text.splitlines()
    blocks, k = [], 0
    while k < len(lines):
        m = _FENCE.match(lines[k])
        if not m:
            k += 1
            continue
        end = next(j for j in range(k + 1, len(lines)) if lines[j].startswith("```"))
        found = _directives(lines, k)
        words = found.get("test", "")
        skip = words[len("skip"):].strip() if words.startswith("skip") else None
        blocks.append(Block(k + 1, m.group(1), "\n".join(lines[k + 1 : end]), found.get("file"),
                            slow="slow" in words.split(), repo="repo" in words.split(), skip=skip))
        k = end + 1
    return blocks


BLOCKS = read_blocks(README.read_text())


def test_every_block_says_what_it_is():
    unknown = [b.id for b in BLOCKS if b.language not in LANGUAGES]
    assert not unknown, f"blocks without a known language ({', '.join(LANGUAGES)}): {unknown}"
    assert all(b.skip for b in BLOCKS if b.skip is not None), "a skipped block must say why"


@dataclass
class Scratch:
    """The folder the blocks run in, and which blocks have run there."""

    folder: Path
    ran: set[int]


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Scratch:
    return Scratch(tmp_path_factory.mktemp("readme"), set())


def needs(block: Block) -> list[Block]:
    """The earlier blocks whose files `block` may use: the runnable ones before it in the scratch folder, slow
    ones only for a slow block (the default run never needs them)."""
    return [b for b in BLOCKS[: BLOCKS.index(block)]
            if b.language != "text" and not b.skip and not b.repo and (block.slow or not b.slow)]


def _environment() -> dict[str, str]:
    """What a user's shell has after `. .venv/bin/activate`: the venv first on PATH, no Vulkan variables."""
    env = {k: v for k, v in os.environ.items() if k not in _VULKAN_VARS}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(Path(sys.executable).parents[1])
    return env


def _shell(command: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-e", "-o", "pipefail", "-c", command], cwd=cwd, env=_environment(),
                          capture_output=True, text=True, timeout=900)


def _line_matches(pattern: str, line: str) -> bool:
    return re.fullmatch(".*".join(re.escape(part) for part in pattern.split("...")), line) is not None


def output_matches(expected: list[str], actual: list[str]) -> bool:
    """Whether `actual` lines fit `expected`, where a line `...` is any lines and `...` in a line any text."""
    if not expected:
        return not actual
    head, rest = expected[0], expected[1:]
    if head.strip() == "...":
        return any(output_matches(rest, actual[k:]) for k in range(len(actual) + 1))
    return bool(actual) and _line_matches(head.rstrip(), actual[0].rstrip()) and output_matches(rest, actual[1:])


def _transcript(body: str) -> list[tuple[str, list[str]]]:
    """(command, expected output lines) of every ``$ `` line of a console block."""
    steps: list[tuple[str, list[str]]] = []
    for line in body.splitlines():
        if line.startswith("$ "):
            steps.append((line[2:], []))
        elif steps:
            steps[-1][1].append(line)
    return steps


def _run_console(block: Block, cwd: Path) -> None:
    status = None
    for command, expected in _transcript(block.body):
        if command.strip() == "echo $?":
            assert [str(status)] == [e.strip() for e in expected], f"{block.id}: exit status {status}, README says {expected}"
            continue
        done = _shell(command, cwd)
        status = done.returncode
        actual = done.stdout.splitlines()
        assert output_matches(expected, actual), (
            f"{block.id}: `{command}` printed\n{done.stdout}{done.stderr}\nREADME shows\n" + "\n".join(expected)
        )


def _run(block: Block, cwd: Path) -> None:
    if block.file is not None:
        (cwd / block.file).write_text(block.body + "\n")
        if block.language == "python":
            done = subprocess.run([sys.executable, block.file], cwd=cwd, env=_environment(), capture_output=True,
                                  text=True, timeout=300)
            assert done.returncode == 0, f"{block.id} ({block.file}):\n{done.stderr[-3000:]}"
        return
    if block.language == "console":
        _run_console(block, cwd)
        return
    if block.language == "python":
        done = subprocess.run([sys.executable, "-c", block.body], cwd=cwd, env=_environment(), capture_output=True,
                              text=True, timeout=900)
    else:
        done = _shell(block.body, cwd)
    assert done.returncode == 0, f"{block.id} failed ({done.returncode}):\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"


def _params() -> list:
    out = []
    for b in BLOCKS:
        if b.language == "text":
            continue
        marks = [pytest.mark.slow] if b.slow else []
        if b.skip:
            marks.append(pytest.mark.skip(reason=b.skip))
        out.append(pytest.param(b, id=b.id, marks=marks))
    return out


@pytest.mark.parametrize("block", _params())
def test_readme_block_runs(block: Block, scratch: Scratch):
    """The block succeeds after the blocks before it, which run first if this run left them out (`-m slow`,
    `-k`), as a reader following the README from the top would have run them."""
    if block.repo:
        _run(block, REPO)
        return
    for earlier in needs(block):
        if earlier.line not in scratch.ran:
            scratch.ran.add(earlier.line)
            _run(earlier, scratch.folder)
    scratch.ran.add(block.line)  # tried: a failed block fails its own test, not every later one again
    _run(block, scratch.folder)


@pytest.mark.parametrize(
    ("expected", "actual", "fits"),
    [
        (["a", "b"], ["a", "b"], True),
        (["a", "b"], ["a", "c"], False),
        (["a", "...", "z"], ["a", "b", "c", "z"], True),
        (["a", "...", "z"], ["a", "z"], True),
        (["a", "..."], ["a"], True),
        (["wrote ... MiB)"], ["wrote pick.rrd (12 KiB)"], False),
        (["wrote ... KiB)"], ["wrote pick.rrd (12 KiB)"], True),
        (["a"], ["a", "b"], False),
    ],
)
def test_transcript_matching(expected, actual, fits):
    assert output_matches(expected, actual) is fits
