"""Every code block of the README and of every page of docs/ runs, so no page can promise what fails; the site builds.

Each page (README.md, docs/*.md) has its own scratch folder, and its blocks run there in order, as a user with the
venv activated would run them (its ``bin/`` first on PATH, no Vulkan variables set: simreel finds its driver
itself); so a page makes what it needs itself, usually with a first block that records. Pages that begin alike
share that work: a page whose first blocks run what another page's first blocks ran starts from a copy of that
page's folder after them, and its transcripts are checked against what those commands printed there (`Desk`).
What each block is says its fence and an optional HTML comment on the line before it:

- ```` ```bash ````: shell commands, run with ``bash -e``; every command must succeed.
- ```` ```python ````: run with the venv's Python; ``<!-- file: NAME.py -->`` before it writes it to NAME.py
  instead (a module the later blocks import), and runs it unless a later block of the page runs ``python NAME.py``.
- ```` ```console ````: a transcript. ``$ command`` lines run; the lines after each are its expected output,
  where a line ``...`` stands for any lines and ``...`` inside a line for any text; ``$ echo $?`` checks
  the exit status of the command before it.
- ```` ```text ````: not code (layouts, trees); not run.
- ``<!-- test: slow -->``: runs only with ``-m slow`` (`make test-all`); ``<!-- test: repo -->``: runs in the
  repository root, not the scratch folder; ``<!-- test: skip REASON -->``: not run, for the reason given.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = REPO / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
README_MAX_LINES = 300
LANGUAGES = ("bash", "python", "console", "text")
_VULKAN_VARS = ("VK_ICD_FILENAMES", "VK_DRIVER_FILES", "VK_ADD_DRIVER_FILES")
_FENCE = re.compile(r"^```(\w*)\s*$")
_DIRECTIVE = re.compile(r"^<!--\s*(test|file):\s*(.*?)\s*-->$")


def _name(page: Path) -> str:
    return page.relative_to(REPO).as_posix()


@dataclass(frozen=True)
class Block:
    page: str
    line: int
    language: str
    body: str
    file: str | None = None
    slow: bool = False
    repo: bool = False
    skip: str | None = None

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}:{self.language}"


def _directives(lines: list[str], fence: int) -> dict[str, str]:
    """The directive comments on the lines just above the fence at index `fence`."""
    found: dict[str, str] = {}
    k = fence - 1
    while k >= 0 and (m := _DIRECTIVE.match(lines[k].strip())):
        found[m.group(1)] = m.group(2)
        k -= 1
    return found


def read_blocks(text: str, page: str = "README.md") -> list[Block]:
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
        blocks.append(Block(page, k + 1, m.group(1), "\n".join(lines[k + 1 : end]), found.get("file"),
                            slow="slow" in words.split(), repo="repo" in words.split(), skip=skip))
        k = end + 1
    return blocks


PAGE_BLOCKS = {_name(p): read_blocks(p.read_text(), _name(p)) for p in PAGES}
BLOCKS = [b for blocks in PAGE_BLOCKS.values() for b in blocks]


def test_every_block_says_what_it_is():
    unknown = [b.id for b in BLOCKS if b.language not in LANGUAGES]
    assert not unknown, f"blocks without a known language ({', '.join(LANGUAGES)}): {unknown}"
    assert all(b.skip for b in BLOCKS if b.skip is not None), "a skipped block must say why"


def test_the_readme_is_short_and_leads_to_every_page():
    text = README.read_text()
    assert len(text.splitlines()) <= README_MAX_LINES, "the README is read in ten minutes: the rest goes to docs/"
    missing = [p.name for p in PAGES[1:] if f"](docs/{p.name})" not in text]
    assert not missing, f"docs pages the README's 'where to go next' does not link: {missing}"


def test_the_pages_speak_to_users():
    """How simreel was developed (its sessions, its issues) belongs to the history, not to what a user reads."""
    talk = re.compile(r"\b(session|issue)s? \d+", re.IGNORECASE)
    found = [f"{_name(p)}:{n}" for p in PAGES for n, line in enumerate(p.read_text().splitlines(), 1)
             if talk.search(line)]
    assert not found, f"development history in the docs (it goes to benchmarks/HISTORY.md): {found}"


def test_the_site_builds_strictly(tmp_path):
    """`make docs`: every page in the nav, no broken link or anchor (mkdocs --strict fails on any warning)."""
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("material") is None:
        pytest.skip("mkdocs and mkdocs-material are not installed (pip install -e '.[docs]', or make docs)")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--config-file",
                           str(REPO / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout}{done.stderr}"


def _runs_in_scratch(block: Block) -> bool:
    return block.language != "text" and not block.skip and not block.repo


def _runs_with(block: Block, other: Block) -> bool:
    """Whether `other` runs in `block`'s scratch folder in a run that runs `block`: slow ones only for a slow
    block (the default run never needs them)."""
    return _runs_in_scratch(other) and (block.slow or not other.slow)


def needs(block: Block) -> list[Block]:
    """The earlier blocks of its page whose files `block` may use, in order."""
    blocks = PAGE_BLOCKS[block.page]
    return [b for b in blocks[: blocks.index(block)] if _runs_with(block, b)]


def runs_later(block: Block) -> bool:
    """Whether a later block of its page that runs when `block` does runs `block`'s file itself."""
    blocks = PAGE_BLOCKS[block.page]
    command = re.compile(rf"\bpython {re.escape(block.file or '')}(\s|$)")
    return any(_runs_with(block, b) and b.language in ("bash", "console") and command.search(b.body)
               for b in blocks[blocks.index(block) + 1 :])


def _transcript(body: str) -> list[tuple[str, list[str]]]:
    """(command, expected output lines) of every ``$ `` line of a console block."""
    steps: list[tuple[str, list[str]]] = []
    for line in body.splitlines():
        if line.startswith("$ "):
            steps.append((line[2:], []))
        elif steps:
            steps[-1][1].append(line)
    return steps


def _commands(block: Block) -> list[str]:
    """What a console block runs: its commands, but the `echo $?` that check the status of the one before."""
    return [c for c, _ in _transcript(block.body) if c.strip() != "echo $?"]


def chain(before: str, block: Block) -> str:
    """The digest of what a page's folder has seen: `before`'s blocks, then `block`. Two pages whose first blocks
    run the same code (a console block: the same commands, whatever output it shows) have the same digests."""
    what = _commands(block) if block.language == "console" else [block.language, block.file or "", block.body]
    return hashlib.sha256(json.dumps([before, *what]).encode()).hexdigest()


def _chains(blocks: list[Block]) -> set[str]:
    digests, digest = set(), ""
    for b in blocks:
        digest = chain(digest, b)
        digests.add(digest)
    return digests


def _shared_beginnings() -> set[str]:
    """The digests that more than one page reaches, in the default run or in one with the slow blocks."""
    seen: dict[str, int] = {}
    for blocks in PAGE_BLOCKS.values():
        runnable = [b for b in blocks if _runs_in_scratch(b)]
        for digest in _chains([b for b in runnable if not b.slow]) | _chains(runnable):
            seen[digest] = seen.get(digest, 0) + 1
    return {d for d, n in seen.items() if n > 1}


SHARED = _shared_beginnings()


@dataclass
class Page:
    """A page's scratch folder, parked while another page's blocks run; which of its blocks have run there, and the
    digest of what they ran (None once one failed: a folder left by a failure is nobody's beginning)."""

    parked: Path
    ran: set[int] = field(default_factory=set)
    digest: str | None = ""


@dataclass
class Desk:
    """The one path, `work`, at which every page's blocks run: the folder of the page whose block runs is moved
    there, the others' parked beside it. One path keeps right what a file says of absolute paths (a replay report
    names its recordings) when a page's folder comes back, and when a page whose first blocks run what another
    page's first blocks ran starts from a copy of that page's folder after them, made at this path, instead of
    running them again; the outputs of their commands are kept with the copy, for its transcripts to check."""

    root: Path
    pages: dict[str, Page] = field(default_factory=dict)
    at: str | None = None
    copies: dict[str, tuple[Path, list[subprocess.CompletedProcess]]] = field(default_factory=dict)

    @property
    def work(self) -> Path:
        return self.root / "work"

    def sit(self, name: str) -> Page:
        """The page `name`, its folder at `work`."""
        if self.at != name:
            if self.at is not None:
                self.work.rename(self.pages[self.at].parked)
            page = self.pages.setdefault(name, Page(self.root / re.sub(r"\W+", "_", name)))
            if page.parked.exists():
                page.parked.rename(self.work)
            else:
                self.work.mkdir()
            self.at = name
        return self.pages[name]

    def run(self, block: Block) -> None:
        page = self.sit(block.page)
        page.ran.add(block.line)
        digest = chain(page.digest, block) if page.digest is not None else None
        if digest in self.copies:
            folder, outputs = self.copies[digest]
            shutil.rmtree(self.work)
            shutil.copytree(folder, self.work, symlinks=True)
            page.digest = digest
            if block.language == "console":
                _check_transcript(block, outputs)
            return
        page.digest = None  # until the block has passed: what a failure leaves is nobody's beginning
        outputs = _run(block, self.work)
        page.digest = digest
        if digest in SHARED:
            shutil.copytree(self.work, self.root / "copies" / digest, symlinks=True)
            self.copies[digest] = (self.root / "copies" / digest, outputs)


@pytest.fixture(scope="module")
def desk(tmp_path_factory) -> Desk:
    return Desk(tmp_path_factory.mktemp("pages"))


_DISPLAY_VARS = ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")


def _environment() -> dict[str, str]:
    """What a user's shell has after `. .venv/bin/activate` on a headless machine (the pages' transcripts show what
    `view` prints there): the venv first on PATH, no Vulkan variables, no display."""
    env = {k: v for k, v in os.environ.items() if k not in _VULKAN_VARS and k not in _DISPLAY_VARS}
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


def _check_transcript(block: Block, outputs: list[subprocess.CompletedProcess]) -> None:
    """What each command of a console block printed (`outputs`, in order) against what the page shows."""
    done = iter(outputs)
    status = None
    for command, expected in _transcript(block.body):
        if command.strip() == "echo $?":
            assert [str(status)] == [e.strip() for e in expected], f"{block.id}: exit status {status}, the page says {expected}"
            continue
        printed = next(done)
        status = printed.returncode
        assert output_matches(expected, printed.stdout.splitlines()), (
            f"{block.id}: `{command}` printed\n{printed.stdout}{printed.stderr}\nthe page shows\n" + "\n".join(expected)
        )


def _run(block: Block, cwd: Path) -> list[subprocess.CompletedProcess]:
    """Runs `block` in `cwd`; a console block's commands' outputs, in order (none for other blocks)."""
    if block.language == "console":
        outputs = [_shell(command, cwd) for command in _commands(block)]
        _check_transcript(block, outputs)
        return outputs
    if block.file is not None:
        (cwd / block.file).write_text(block.body + "\n")
        if block.language == "python" and not runs_later(block):
            done = subprocess.run([sys.executable, block.file], cwd=cwd, env=_environment(), capture_output=True,
                                  text=True, timeout=300)
            assert done.returncode == 0, f"{block.id} ({block.file}):\n{done.stderr[-3000:]}"
        return []
    if block.language == "python":
        done = subprocess.run([sys.executable, "-c", block.body], cwd=cwd, env=_environment(), capture_output=True,
                              text=True, timeout=900)
    else:
        done = _shell(block.body, cwd)
    assert done.returncode == 0, f"{block.id} failed ({done.returncode}):\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    return []


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
def test_block_runs(block: Block, desk: Desk):
    """The block succeeds after the blocks before it on its page, which run first if this run left them out
    (`-m slow`, `-k`), as a reader following the page from the top would have run them."""
    if block.repo:
        _run(block, REPO)
        return
    page = desk.sit(block.page)
    for earlier in needs(block):
        if earlier.line not in page.ran:
            desk.run(earlier)
    desk.run(block)  # tried: a failed block fails its own test, not every later one again


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


def test_blocks_are_read_with_their_page_and_directives():
    page = "\n".join(["intro", "<!-- test: slow -->", "<!-- file: m.py -->", "```python", "x = 1", "```",
                      "```console", "$ python m.py", "```"])
    blocks = read_blocks(page, "docs/x.md")
    assert [b.id for b in blocks] == ["docs/x.md:4:python", "docs/x.md:7:console"]
    assert blocks[0].file == "m.py" and blocks[0].slow and not blocks[1].slow
