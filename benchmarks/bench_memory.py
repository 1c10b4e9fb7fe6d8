"""Peak memory of `simreel inspect`, `replay`, `view`, `convert`, `merge`, `filter` and `recover` on a long episode
against a short one (target ≤ 1.2×).

Records one `--short`-step and one `--long`-step episode of `--env` (random actions, the CLI's defaults, the
time limit set by --max-steps) into `--folder` (kept and reused when it already holds them), then runs each
command once per recording in a fresh process and reads that process's peak resident set size (`wait4`);
`convert` (with and without `--poses`), `merge` (of the recording alone) and `recover` (of the intact recording,
which copies it) write the other format (HDF5 → MCAP, MCAP → HDF5), `filter` (its episode 0), `convert --obs-mode
state` (a re-render: every state restored and checked, its observations computed) and `convert --control-mode
pd_joint_pos --obs-mode state` (the recording's pd_joint_delta_pos actions converted, stepped and tracked) the same:

    .venv/bin/python benchmarks/bench_memory.py                       # PickCube-v1, 200 vs 20,000 steps
    .venv/bin/python benchmarks/bench_memory.py --format mcap --folder /tmp/mem
    .venv/bin/python benchmarks/bench_memory.py --cameras             # also episodes with 128x128 rgb frames
    .venv/bin/python benchmarks/bench_memory.py --output              # also `replay -o --workers 2`

With `--output` two more recordings of two episodes each (`--short` and `--long` steps) are replayed with
`-o OUT --workers 2`: both episodes go to the pool's worker process, so this measures what an episode replayed in
another process costs the run. A pool's processes are measured together: the peak of the sum of the resident set
sizes of the command's process and its descendants, read from /proc every 20 ms (shared pages count once per
process, so the sum is above what the machine lends; the difference long - short is what a long episode adds).

With `--cameras` (HDF5 only) the same two episodes are also written with camera frames: every state row gets the
observations (128x128 rgb frame, agent and extra state) of a row of a real 30-step `--obs-mode rgb --record-obs`
recording of the env, in turn (recording 20,000 rendered steps on a CPU takes ~25 min; the bytes a reader holds do
not depend on which frames they are). Those are replayed with `--obs-mode state`: the frames are read, block by
block, and not compared (re-rendering them would be the same ~70 ms per step); the states are verified. `view --save`
logs every frame into the .rrd, read from the file a block at a time.

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

import numpy as np

SIMREEL = Path(sys.executable).with_name("simreel")


def _record(env_id: str, steps: int, path: Path) -> None:
    if path.exists():
        return
    t0 = time.perf_counter()
    subprocess.run([str(SIMREEL), "record", env_id, "-o", str(path), "--max-steps", str(steps), "--seed", "0", "-q"],
                   check=True, stdout=subprocess.DEVNULL)
    print(f"recorded {path.name}: {steps} steps in {time.perf_counter() - t0:.0f} s", file=sys.stderr)


def _with_frames(path: Path, frames: Path, out: Path) -> None:
    """`path` (one state-only episode) written to `out` with the observations of `frames` (a short recording with
    camera observations) repeated row after row, a block at a time (`simreel.formats` writer API)."""
    import dataclasses

    from simreel.formats import open_reader, open_writer
    from simreel.model.blocks import StepBlock

    if out.exists():
        return
    with open_reader(frames) as f:
        cam_meta = f.meta
        obs = {k: a for k, a in f.read_episode(f.episodes[0].index).fields().items() if k.startswith("obs/")}
    period = len(next(iter(obs.values())))
    with open_reader(path) as reader:
        meta = dataclasses.replace(reader.meta, obs_mode=cam_meta.obs_mode, obs_layout=cam_meta.obs_layout)
        rows = reader.open_episode(reader.episodes[0].index)

        def with_obs(block: StepBlock, first_row: int) -> StepBlock:
            picked = (np.arange(first_row, first_row + block.rows)) % period
            return StepBlock.of({**block.arrays, **{k: a[picked] for k, a in obs.items()}})

        with open_writer(out, meta) as writer:
            sink = writer.begin_episode(rows.meta, with_obs(rows.reset(), 0))
            for first, block in rows.blocks(256):
                sink.append(with_obs(block, first + 1))
            sink.commit(rows.meta)


def _check_finished(proc: subprocess.Popen, argv: list[str]) -> None:
    """Stop the benchmark unless `argv` ran to its end: exit 0, or 1 (an episode did not verify, e.g. a long random
    episode's contact forces in a re-render: the run still read, checked and wrote everything)."""
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr.read().decode()[-500:]}")


def _peak_mib(argv: list[str]) -> tuple[float, float]:
    """Peak RSS (MiB) and wall seconds of one run of `argv`, which must run to its end (`_check_finished`)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    _check_finished(proc, argv)
    return usage.ru_maxrss / 1024, time.perf_counter() - t0


def _tree_rss_kib(pid: int) -> int:
    """Resident set size (KiB) of `pid` and every process below it, summed (0 for those already gone)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    tree, grown = {pid}, True
    while grown:
        below = {p for p, parent in parents.items() if parent in tree} - tree
        tree |= below
        grown = bool(below)
    total = 0
    for p in tree:
        try:
            status = Path(f"/proc/{p}/status").read_text()
        except OSError:
            continue
        total += next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")), 0)
    return total


def _tree_peak_mib(argv: list[str]) -> tuple[float, float]:
    """Peak of the summed RSS (MiB) of one run of `argv` and its child processes, and its wall seconds."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, _tree_rss_kib(proc.pid))
        time.sleep(0.02)
    _check_finished(proc, argv)
    return peak / 1024, time.perf_counter() - t0


def _commands(path: Path, scratch: Path) -> dict[str, list[str]]:
    sim = str(SIMREEL)
    return {
        "inspect": [sim, "inspect", str(path)],
        "replay": [sim, "replay", str(path), "-q", "--report", str(scratch / f"{path.stem}.report.json"),
                   "--overwrite"],
        "view --save": [sim, "view", str(path), "--save", str(scratch / f"{path.stem}.rrd"), "--overwrite"],
        **_copy_commands(path, scratch),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env", default="PickCube-v1")
    p.add_argument("--short", type=int, default=200)
    p.add_argument("--long", type=int, default=20_000)
    p.add_argument("--format", default="h5", choices=("h5", "mcap"))
    p.add_argument("--folder", default="/tmp/simreel_bench_memory", help="where the recordings are kept")
    p.add_argument("--cameras", action="store_true", help="also episodes with camera frames (see above)")
    p.add_argument("--output", action="store_true", help="also `replay -o --workers 2` of two episodes (see above)")
    args = p.parse_args()

    folder = Path(args.folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {n: folder / f"{args.env}.{n}.{args.format}" for n in (args.short, args.long)}
    for steps, path in paths.items():
        _record(args.env, steps, path)
    print(f"{args.env}, one episode of {args.short} vs {args.long} steps, {args.format}")
    print(f"  {'command':<15} {'short MiB':>10} {'long MiB':>9} {'ratio':>6}  {'long s':>7}")
    _table(paths, _commands, folder)
    if args.output:
        _output_table(args, folder)
    if args.cameras:
        frames = folder / f"{args.env}.frames.h5"
        if not frames.exists():
            subprocess.run([str(SIMREEL), "record", args.env, "-o", str(frames), "--obs-mode", "rgb", "--record-obs",
                            "--max-steps", "30", "--seed", "0", "-q"], check=True, stdout=subprocess.DEVNULL)
        cams = {n: folder / f"{args.env}.{n}.rgb.h5" for n in paths}
        for n, path in paths.items():
            _with_frames(path, frames, cams[n])
        size = cams[args.long].stat().st_size / 2**20
        print(f"the same episodes with a 128x128 rgb camera frame per state row (the long one {size:.0f} MiB on disk)")
        print(f"  {'command':<15} {'short MiB':>10} {'long MiB':>9} {'ratio':>6}  {'long s':>7}")
        _table(cams, _camera_commands, folder)
    return 0


def _output_table(args: argparse.Namespace, folder: Path) -> None:
    """`replay -o --workers 2` of two episodes of `--short` and of `--long` steps: the peak of the process tree."""
    paths = {}
    for steps in (args.short, args.long):
        path = paths[steps] = folder / f"{args.env}.2x{steps}.{args.format}"
        if not path.exists():
            subprocess.run([str(SIMREEL), "record", args.env, "-o", str(path), "-n", "2", "--max-steps", str(steps),
                            "--seed", "0", "-q"], check=True, stdout=subprocess.DEVNULL)
    print(f"two episodes of {args.short} vs {args.long} steps, replay -o --workers 2 (peak of the summed RSS of the "
          "process tree)")
    print(f"  {'command':<15} {'short MiB':>10} {'long MiB':>9} {'ratio':>6}  {'long s':>7}  {'long - short MiB':>16}")
    runs = {}
    for steps, path in paths.items():
        out = folder / f"{path.stem}.replayed.{args.format}"
        runs[steps] = _tree_peak_mib([str(SIMREEL), "replay", str(path), "-q", "-o", str(out), "--workers", "2",
                                      "--overwrite"])
    (short, _), (long, seconds) = runs.values()
    print(f"  {'replay -o':<15} {short:>10.0f} {long:>9.0f} {long / short:>6.2f}  {seconds:>7.0f}  "
          f"{long - short:>16.0f}   [target <= 1.2]")


def _camera_commands(path: Path, scratch: Path) -> dict[str, list[str]]:
    sim = str(SIMREEL)
    return {
        "inspect": [sim, "inspect", str(path)],
        "replay": [sim, "replay", str(path), "-q", "--obs-mode", "state", "--report",
                   str(scratch / f"{path.stem}.report.json"), "--overwrite"],
        "view --save": [sim, "view", str(path), "--save", str(scratch / f"{path.stem}.rrd"), "--overwrite"],
        "video --camera": [sim, "video", str(path), "--camera", "base_camera", "--size", "128x128", "-o", str(scratch),
                           "-q", "--overwrite"],
        **_copy_commands(path, scratch),
    }


def _copy_commands(path: Path, scratch: Path) -> dict[str, list[str]]:
    """`convert` (with and without `--poses`), `merge` (of the recording alone) and `recover` (of the intact
    recording, which copies it) to the other format, `filter` (its episode 0), a re-render (`convert --obs-mode
    state`: every state restored, its observations computed and checked) and a control-mode conversion (to
    pd_joint_pos, with state observations) to the same."""
    sim, other = str(SIMREEL), ".mcap" if path.suffix == ".h5" else ".h5"
    return {
        "convert": [sim, "convert", str(path), str(scratch / f"{path.stem}.converted{other}"), "-q", "--overwrite"],
        "convert --poses": [sim, "convert", str(path), str(scratch / f"{path.stem}.posed{other}"), "--poses", "-q",
                            "--overwrite"],
        "convert --obs-mode": [sim, "convert", str(path), str(scratch / f"{path.stem}.rerendered{path.suffix}"),
                               "--obs-mode", "state", "-q", "--overwrite"],
        "convert --control-mode": [sim, "convert", str(path), str(scratch / f"{path.stem}.joint{path.suffix}"),
                                   "--control-mode", "pd_joint_pos", "--obs-mode", "state", "-q", "--overwrite"],
        "merge": [sim, "merge", str(path), "-o", str(scratch / f"{path.stem}.merged{other}"), "-q",
                  "--overwrite"],
        "filter": [sim, "filter", str(path), "-o", str(scratch / f"{path.stem}.filtered{path.suffix}"), "--episodes",
                   "0", "-q", "--overwrite"],
        "recover": [sim, "recover", str(path), "-o", str(scratch / f"{path.stem}.recovered{other}"), "--overwrite"],
    }


def _table(paths: dict[int, Path], commands, scratch: Path) -> None:
    """One line per command: peak RSS on the short and on the long recording, and their ratio."""
    short_path, long_path = paths.values()
    for name in commands(short_path, scratch):
        (short, _), (long, seconds) = (_peak_mib(commands(path, scratch)[name]) for path in (short_path, long_path))
        print(f"  {name:<15} {short:>10.0f} {long:>9.0f} {long / short:>6.2f}  {seconds:>7.0f}   [target <= 1.2]")


if __name__ == "__main__":
    sys.exit(main())
