"""Dataset conversion: `simreel convert` (verifying every step) against ManiSkill's `replay_trajectory` doing the
same conversion of the same episodes, in one run: throughput (recorded steps per second) and output bytes per step.

The demos are recorded here with ManiSkill's own RecordEpisode, the way its published demos are (pd_joint_pos,
no observations, env states): PickCube grasp-and-lift demos planned with inverse kinematics (the test fixtures'
generator). Each conversion runs alternately with each tool, ``--rounds`` times after a warm-up round; the best
round of each is compared (the machine may be shared), the median and the CPU time (this process, all threads,
the software renderer's included: less sensitive to other load than wall time) printed too. Each round builds
its env, as a run of either tool does; the first frame of a new env costs most of a round (lavapipe).

    .venv/bin/python benchmarks/bench_convert.py                         # control mode: -> pd_ee_delta_pose
    .venv/bin/python benchmarks/bench_convert.py --what rgb              # re-render rgb (lavapipe on a CPU)
    .venv/bin/python benchmarks/bench_convert.py --what pointcloud --episodes 2
    .venv/bin/python benchmarks/bench_convert.py --format mcap              # simreel writes MCAP (zstd) instead

What each tool does for the same output:

- control (``-c pd_ee_delta_pose`` / ``--control-mode pd_ee_delta_pose``): ManiSkill steps an env in the original
  mode beside the converted one and judges an episode by its final success; simreel steps the converted one and
  compares command, tool-centre pose, objects and success with the recorded states at every step.
- rgb / pointcloud (``-o rgb --use-env-states`` / ``--obs-mode rgb``): both restore each recorded state and
  render, on the same device with the env's default cameras and shader, T + 2 frames per episode of T steps
  (the reset's, the first state's, one per step); simreel checks each restore and the recomputed rewards, then
  reads the written file back.
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

REPO = Path(__file__).resolve().parents[1]


def _quiet() -> contextlib.ExitStack:
    stack = contextlib.ExitStack()
    stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
    stack.enter_context(contextlib.redirect_stderr(io.StringIO()))
    return stack


def _demos(folder: Path, episodes: int, steps: int) -> Path:
    sys.path.insert(0, str(REPO / "tests"))
    from support.maniskill_files import record_maniskill

    with _quiet():
        return record_maniskill(folder, "PickCube-v1", name="demos", episodes=episodes, steps=steps, path="pick")


def _size(path: Path) -> int:
    """The recording's bytes, with its JSON sidecar where it has one (HDF5)."""
    sidecar = path.with_suffix(".json")
    return path.stat().st_size + (sidecar.stat().st_size if sidecar.exists() else 0)


def _runners(src: Path, what: str, out: Path) -> dict[str, Any]:
    """The two conversions, each a function returning (output file, verified episodes or None)."""
    from mani_skill.trajectory import replay_trajectory as ms_replay

    from simreel.replay.convert.convert import convert_recording

    ms_args = ["--traj-path", str(src), "--save-traj", "--allow-failure"]
    ms_args += ["-c", "pd_ee_delta_pose"] if what == "control" else ["-o", what, "--use-env-states"]
    options = {"control_mode": "pd_ee_delta_pose"} if what == "control" else {"obs_mode": what}

    def maniskill() -> tuple[Path, None]:
        with _quiet():
            ms_replay.main(ms_replay.parse_args(ms_args))
        return next(p for p in src.parent.glob("demos.*.h5")), None

    def simreel() -> tuple[Path, int]:
        report = convert_recording(src, out, overwrite=True, **options)
        return out, sum(e.ok for e in report.episodes)

    return {"maniskill": maniskill, "simreel": simreel}


def _rounds(runners: dict[str, Any], rounds: int) -> tuple[dict[str, list[float]], dict[str, list[float]], dict[str, Any]]:
    """Wall and CPU seconds (this process, all its threads: the software renderer's included) of each round."""
    last: dict[str, Any] = {}
    for name, fn in runners.items():  # warm-up: first env builds, imports, file cache
        last[name] = fn()
    wall: dict[str, list[float]] = {name: [] for name in runners}
    cpu: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(rounds):
        for name, fn in runners.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            last[name] = fn()
            wall[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    return wall, cpu, last


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--what", choices=("control", "rgb", "pointcloud"), default="control")
    p.add_argument("--episodes", type=int, default=None, help="default: 10 (control), 3 (images)")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--format", choices=("h5", "mcap"), default="h5", help="what simreel writes (ManiSkill: HDF5)")
    args = p.parse_args()
    episodes = args.episodes or (10 if args.what == "control" else 3)

    from simreel.sim.render_device import configure_vulkan

    configure_vulkan()  # before sapien loads: ManiSkill's tool finds lavapipe where there is no GPU
    warnings.filterwarnings("ignore")
    tmp = Path(tempfile.mkdtemp(prefix="bench_convert_"))
    try:
        src = _demos(tmp, episodes, args.steps)
        steps = episodes * args.steps
        runners = _runners(src, args.what, tmp / f"simreel.{args.format}")
        wall, cpu, last = _rounds(runners, args.rounds)
        print(f"PickCube-v1, {episodes} pd_joint_pos demos x {args.steps} steps ({steps} steps), conversion: {args.what}; "
              f"{args.rounds} rounds each after a warm-up; simreel writes {args.format}")
        for name, label in (("maniskill", "ManiSkill replay_trajectory"), ("simreel", "simreel convert (verifies)")):
            best, med = min(wall[name]), statistics.median(wall[name])
            size = _size(last[name][0])
            print(f"  {label:<30} best {best:7.2f} s = {steps / best:6.1f} steps/s, median {med:7.2f} s, "
                  f"CPU {min(cpu[name]):7.2f} s; output {size / steps:8.0f} B/step ({size / 1024:.0f} KiB with its JSON)")
        ratio = min(wall["maniskill"]) / min(wall["simreel"])
        med_ratio = statistics.median(wall["maniskill"]) / statistics.median(wall["simreel"])
        cpu_ratio = min(cpu["maniskill"]) / min(cpu["simreel"])
        bytes_ratio = _size(last["simreel"][0]) / _size(last["maniskill"][0])
        print(f"simreel / ManiSkill: throughput {ratio:.2f}x (best rounds), {med_ratio:.2f}x (medians), {cpu_ratio:.2f}x "
              f"(CPU time) [target >= 1.0]; bytes {bytes_ratio:.2f}x [target <= 0.7]")
        print(f"simreel verified {last['simreel'][1]} of {episodes} episodes")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
