"""Recordings the replay tests share: made once per session, in-process, state-only (no render device needed)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from simreel.cli.main import main


@pytest.fixture(scope="session")
def record(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    """`record(env_id, n=2, steps=20, *extra_args)` → path of a fresh recording (cached per argument list)."""
    cache: dict[tuple, Path] = {}
    folder = tmp_path_factory.mktemp("recordings")

    def _record(env_id: str, n: int = 2, steps: int = 20, *extra: str) -> Path:
        key = (env_id, n, steps, *extra)
        if key not in cache:
            out = folder / f"{len(cache):02d}_{env_id}.h5"
            args = ["record", env_id, "-o", str(out), "-n", str(n), "--max-steps", str(steps), "--seed", "3",
                    "--render-backend", "none", "-q", *extra]
            if env_id.startswith("Simreel"):
                args += ["--policy", "scripted", "--import", "simreel.tasks"]
            assert main(args) == 0
            cache[key] = out
        return cache[key]

    return _record
