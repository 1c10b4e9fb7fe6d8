"""Peak memory of `simreel inspect`, `replay` and `view` on a long episode against a short one (target ≤ 1.2×).

Records one `--short`-step and one `--long`-step episode of `--env` (random actions, the CLI's defaults, the
time limit set by --max-steps) into `--folder` (kept and reused when it already holds them), then runs each
command once per recording in a fresh process and reads that process's peak resident set size (`wait4`):

    .venv/bin/python benchmarks/bench_memory.py                       # PickCube-v1, 200 vs 20,000 steps
    .venv/bin/python benchmarks/bench_memory.py --format mcap --folder /tmp/mem

The peak includes the interpreter, torch, SAPIEN and the env (~0.5 GiB), which every run pays once; what a
long episode adds on top of that is what the ratio shows.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

SIMREEL = Path(sys.executable).with_name("simreel")


def _record(env_id: str, steps: int, path: Path) -> None:
    if path.exists():
        return
    t0 = time.perf_counter()
    subprocess.run([str(SIMREEL), "record", env_id, "-o", str(path), "--max-steps", str(steps), "--seed", "0", "-q"],
                   check=True, stdout=subprocess.DEVNULL)
    print(f"recorded {path.name}: {steps} steps in {time.perf_counter() - t0:.0f} s", file=sys.stderr)


def _peak_mib(argv: list[str]) -> tuple[float, float]:
    """Peak RSS (MiB) and wall seconds of one run of `argv`, which must succeed."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.read().decode()[-500:]}")
    return usage.ru_maxrss / 1024, time.perf_counter() - t0


def _commands(path: Path, scratch: Path) -> dict[str, list[str]]:
    sim = str(SIMREEL)
    return {
        "inspect": [sim, "inspect", str(path)],
        "replay": [sim, "replay", str(path), "-q", "--report", str(scratch / f"{path.stem}.report.json"),
                   "--overwrite"],
        "view --save": [sim, "view", str(path), "--save", str(scratch / f"{path.stem}.rrd"), "--overwrite"],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="PickCube-v1")
    p.add_argument("--short", type=int, default=200)
    p.add_argument("--long", type=int, default=20_000)
    p.add_argument("--format", default="h5", choices=("h5", "mcap"))
    p.add_argument("--folder", default="/tmp/simreel_bench_memory", help="where the recordings are kept")
    args = p.parse_args()

    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {n: folder / f"{args.env}.{n}.{args.format}" for n in (args.short, args.long)}
    for steps, path in paths.items():
        _record(args.env, steps, path)
    print(f"{args.env}, one episode of {args.short} vs {args.long} steps, {args.format}")
    print(f"  {'command':<12} {'short MiB':>10} {'long MiB':>9} {'ratio':>6}  {'long s':>7}")
    for name in _commands(folder, folder):
        (short, _), (long, seconds) = (_peak_mib(_commands(path, folder)[name]) for path in paths.values())
        print(f"  {name:<12} {short:>10.0f} {long:>9.0f} {long / short:>6.2f}  {seconds:>7.0f}   [target <= 1.2]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
