"""Replay-with-verification throughput: `simreel replay` against ManiSkill's `replay_trajectory`, same recording.

Both run in this one process, alternately, ``--rounds`` times each (the machine may be shared: the best
round of each is compared, the median is printed too). ManiSkill's tool steps the recorded actions and
judges the final ``success`` only; simreel rebuilds the env the same way, reproduces each reset, steps the
actions and compares every state-dict leaf, reward, flag, info entry and contact force at every step.

    .venv/bin/python benchmarks/bench_replay.py                      # records PickCube-v1, 20 x 50 steps
    .venv/bin/python benchmarks/bench_replay.py --recording x.h5 --rounds 7
    .venv/bin/python benchmarks/bench_replay.py --save-traj          # ManiSkill also writes its replayed file
    .venv/bin/python benchmarks/bench_replay.py --maniskill          # on a file ManiSkill itself wrote

With ``--maniskill`` the replayed file is one ManiSkill's own tools wrote (its RecordEpisode, inside
`replay_trajectory --save-traj` of the recording): no simreel metadata, state observations, no rewards; simreel
reads it as a ManiSkill trajectory file and verifies what it holds (states, observations, flags). The file holds
no rewards: simreel does not compute them (``reward_mode="none"``), ManiSkill's tool computes them and drops them.

ManiSkill's tool builds its env with ``render_mode="rgb_array"``, which needs a Vulkan device; simreel finds
the software one (lavapipe, `make setup`) itself. Without any device the benchmark installs simreel's
no-render layer (`simreel.sim.norender`) for ManiSkill too: it changes how scenes are built, not the per-step work.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any


def _record(path: Path, env_id: str, episodes: int, steps: int) -> None:
    from simreel.cli.main import main

    code = main(["record", env_id, "-o", str(path), "-n", str(episodes), "--max-steps", str(steps),
                 "--render-backend", "none", "--seed", "0", "-q", "--overwrite"])
    if code != 0:
        raise SystemExit(f"recording failed ({code})")


def _quiet() -> contextlib.ExitStack:
    stack = contextlib.ExitStack()
    stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
    stack.enter_context(contextlib.redirect_stderr(io.StringIO()))
    return stack


def _prepare(args: argparse.Namespace, tmp: Path) -> Path:
    """The recording to replay, copied (or recorded) into `tmp`."""
    if not args.recording:
        rec = tmp / f"{args.env_id}.h5"
        _record(rec, args.env_id, args.episodes, args.steps)
        return rec
    src = Path(args.recording)
    rec = tmp / src.name
    shutil.copy(src, rec)
    shutil.copy(src.with_suffix(".json"), rec.with_suffix(".json"))
    return rec


def _as_maniskill_file(rec: Path, ms_replay: Any) -> Path:
    """The recording rewritten by ManiSkill's own RecordEpisode (replay_trajectory --save-traj), moved into a
    folder of its own so that nothing else there is taken for it."""
    with _quiet():
        ms_replay.main(ms_replay.parse_args(["--traj-path", str(rec), "--save-traj", "--allow-failure"]))
    written = next(p for p in rec.parent.glob(f"{rec.stem}.*.h5"))
    folder = rec.parent / "maniskill"
    folder.mkdir()
    for path in (written, written.with_suffix(".json")):
        path.rename(folder / path.name.replace(f"{rec.stem}.", "demos."))
    return next(folder.glob("*.h5"))


def _ensure_render_or_norender() -> None:
    import sapien

    try:
        sapien.render.get_device_summary()
    except Exception:  # noqa: BLE001 - no Vulkan device at all
        from simreel.sim import norender

        norender.install()
        print("no render device: ManiSkill's tool runs with simreel.sim.norender installed")


def _timed(fn: Any) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def _rounds(runners: dict[str, Any], rounds: int) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Each runner once to warm up (first env build, file cache), then `rounds` times, alternately."""
    for fn in runners.values():
        fn()
    wall: dict[str, list[float]] = {name: [] for name in runners}
    cpu: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(rounds):
        for name, fn in runners.items():
            w, c = _timed(fn)
            wall[name].append(w)
            cpu[name].append(c)
    return wall, cpu


def _print_results(wall: dict[str, list[float]], cpu: dict[str, list[float]], steps: int, save_traj: bool) -> None:
    for name, label in (("maniskill", "ManiSkill replay_trajectory" + (" --save-traj" if save_traj else "")),
                        ("simreel", "simreel replay (verifies every step)")):
        best, med = min(wall[name]), statistics.median(wall[name])
        print(f"  {label:<42} wall best {best:6.3f} s = {steps / best:5.0f} steps/s, median {med:6.3f} s;"
              f" CPU best {min(cpu[name]):6.3f} s")
    ratios = {
        "wall, best rounds": min(wall["maniskill"]) / min(wall["simreel"]),
        "wall, medians": statistics.median(wall["maniskill"]) / statistics.median(wall["simreel"]),
        "CPU time, best rounds": min(cpu["maniskill"]) / min(cpu["simreel"]),
    }
    print("throughput ratio simreel / ManiSkill: " + ", ".join(f"{v:.2f} ({k})" for k, v in ratios.items())
          + "   [target >= 1.0]")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recording", default=None, help="a simreel .h5 recording (default: record one)")
    p.add_argument("--env-id", default="PickCube-v1")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--save-traj", action="store_true", help="ManiSkill also writes its replayed trajectory")
    p.add_argument("--maniskill", action="store_true", help="replay a file written by ManiSkill's own RecordEpisode")
    args = p.parse_args()

    from simreel.sim.render_device import configure_vulkan

    configure_vulkan()  # before sapien loads: lets ManiSkill's tool find lavapipe where there is no GPU
    warnings.filterwarnings("ignore")
    tmp = Path(tempfile.mkdtemp(prefix="bench_replay_"))
    try:
        rec = _prepare(args, tmp)
        _ensure_render_or_norender()
        from mani_skill.trajectory import replay_trajectory as ms_replay

        if args.maniskill:
            rec = _as_maniskill_file(rec, ms_replay)

        from simreel.formats import open_reader
        from simreel.replay.run.verify import verify_recording

        with open_reader(rec) as r:
            steps, n_eps, env_id = sum(m.length for m in r.episodes), len(r.episodes), r.meta.env_id
        ms_args = ["--traj-path", str(rec), "--allow-failure"] + (["--save-traj"] if args.save_traj else [])
        exact = []

        def run_maniskill() -> None:
            with _quiet():
                ms_replay.main(ms_replay.parse_args(ms_args))

        def run_simreel() -> None:
            report = verify_recording(rec)
            exact.append(report.ok and all(e.verdict == "exact" for e in report.episodes))

        wall, cpu = _rounds({"maniskill": run_maniskill, "simreel": run_simreel}, args.rounds)
        kind = "a ManiSkill RecordEpisode file" if args.maniskill else "a simreel recording"
        print(f"{kind}: {env_id}, {n_eps} episodes, {steps} steps (CPU sim, state obs); {args.rounds} rounds each")
        _print_results(wall, cpu, steps, args.save_traj)
        print(f"simreel verdicts: {'every episode exact' if all(exact) else 'NOT all exact'}")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
