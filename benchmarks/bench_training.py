"""Training data: the LeRobot export and the torch dataset against ManiSkill's own tools, on the same episodes, in
one run.

1. Export: `simreel export --to lerobot` against ManiSkill's `python -m mani_skill.trajectory.convert_to_lerobot`
   on one simreel PickCube-v1 recording with a 128×128 camera (`--obs-mode rgb --record-obs`; simreel's HDF5 is
   ManiSkill's layout, which the converter reads). Each tool runs as a user runs it, a fresh process, alternately,
   ``--rounds`` times; the best wall time of each is compared, frames per second and bytes written printed. The
   converter needs pandas and opencv, which simreel does not install (``pip install pandas
   opencv-python-headless``); it is skipped, saying so, without them. What each writes differs: ManiSkill one mp4v
   video per episode at the fps given (here 20, the env's control rate), `observation.state` = `agent/qpos`;
   simreel H.264 videos, episodes concatenated, the whole observation as the state, rewards, success, done, the
   statistics with quantiles and the provenance. ``--workers 1,2`` times simreel's export with each worker count
   too, side by side, alternately, and prints the ratio to one worker (on a machine whose cores others share, the
   figure moves with their load).
2. Loader: DataLoader samples/s over state windows of a state-obs recording (batch 64, one process, one pass):
   `RecordingDataset` (observation history 1 and 2, action chunk 1 and 8; ``collate_fn=ds.collate`` and torch's
   default collate) against ManiSkill's `ManiSkillTrajectoryDataset` (single frames: the obs dict and the action;
   it loads the whole file first, which its building time, imports included, is printed apart) and against
   LeRobot's `LeRobotDataset` on the `simreel export --to lerobot` copy of the same recording, with
   `delta_timestamps` giving the same windows (fps 20), run in LeRobot's venv (`make lerobot-env`; skipped, saying
   so, without it). The same on camera windows of the export's rgb recording, against ManiSkill's dataset only
   (LeRobot's video decoders do not run in its venv here).
3. Memory: the peak RSS of a fresh process that builds each dataset and reads every sample once, for the recording
   and for one with ``--scale`` times its episodes.

    .venv/bin/python benchmarks/bench_training.py                          # 10 rgb episodes, 20 / 200 state ones
    .venv/bin/python benchmarks/bench_training.py --episodes 4 --state-episodes 10 --scale 10 --rounds 2
    .venv/bin/python benchmarks/bench_training.py --workers 1,2 --skip-loader     # export: 1 and 2 workers
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
SIMREEL = str(Path(PYTHON).parent / "simreel")
STEPS = 50


def _record(out: Path, episodes: int, *extra: str) -> Path:
    subprocess.run([SIMREEL, "record", "PickCube-v1", "-o", str(out), "-n", str(episodes), "--max-steps",
                    str(STEPS), "--seed", "7", "--record-obs", "-q", *extra], check=True, capture_output=True)
    return out


def _bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def _timed(command: list[str], env: dict[str, str] | None = None, cpu: list[float] | None = None) -> float:
    """The wall time of `command`, run to its end; its CPU time (its processes', ffmpeg's included) appended to
    `cpu` where given."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:4])} ... failed: {(done.stderr or done.stdout).strip()[-500:]}")
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if cpu is not None:
        cpu.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return wall


def _converter_runs() -> str | None:
    """Why ManiSkill's converter cannot run here, or None."""
    missing = [m for m in ("pandas", "cv2") if subprocess.run([PYTHON, "-c", f"import {m}"],
                                                              capture_output=True).returncode]
    return f"ManiSkill's convert_to_lerobot needs {', '.join(missing)} (pip install pandas opencv-python-headless)" \
        if missing else None


def bench_export(folder: Path, rec: Path, rounds: int, workers: tuple[int, ...] = (1,)) -> None:
    frames = STEPS * _episode_count(rec)
    why_not = _converter_runs()
    simreel = {n: "simreel" if n == 1 else f"simreel -w{n}" for n in workers}
    times: dict[str, list[float]] = {**{label: [] for label in simreel.values()}, "maniskill": []}
    cpu: dict[str, list[float]] = {label: [] for label in times}
    sizes = {}
    for k in range(rounds):
        for n, label in simreel.items():  # alternately, so that the machine's load falls on each alike
            out = folder / f"simreel_{n}_{k}"
            times[label].append(_timed([SIMREEL, "export", str(rec), "--to", "lerobot", str(out), "--workers", str(n),
                                        "-q"], cpu=cpu[label]))
            sizes[label] = _bytes(out)
        if why_not is None:
            out = folder / f"maniskill_{k}"
            times["maniskill"].append(_timed([PYTHON, "-m", "mani_skill.trajectory.convert_to_lerobot", "--traj-path",
                                              str(rec), "--output-dir", str(out), "--fps", "20", "--image-size",
                                              "128x128"], env={**os.environ, "PYTHONWARNINGS": "ignore"},
                                             cpu=cpu["maniskill"]))
            sizes["maniskill"] = _bytes(out)
    print(f"export of {_episode_count(rec)} episodes x {STEPS} steps, one 128x128 camera (best of {rounds}):")
    for tool, runs in times.items():
        if runs:
            best = min(runs)
            print(f"  {tool:12s} {best:7.2f} s  {frames / best:8.1f} frames/s  {sizes[tool] / frames:9.1f} B/frame "
                  f"({sizes[tool] / 2**20:.2f} MiB; runs {', '.join(f'{t:.2f}' for t in runs)} s; CPU "
                  f"{', '.join(f'{t:.2f}' for t in cpu[tool])} s)")
    for n, label in simreel.items():
        if n != 1 and 1 in simreel:
            print(f"  --workers {n}: {min(times['simreel']) / min(times[label]):.2f}x the throughput of one worker "
                  f"({os.cpu_count()} CPU(s) here)")
    if why_not:
        print(f"  maniskill  not run: {why_not}")
    elif "simreel" in times:
        ratio = min(times["maniskill"]) / min(times["simreel"])
        print(f"  simreel throughput {ratio:.2f}x ManiSkill's; bytes {sizes['simreel'] / sizes['maniskill']:.2f}x")


def _episode_count(rec: Path) -> int:
    return len(json.loads(rec.with_suffix(".json").read_text())["episodes"])


LEROBOT_PYTHON = REPO / ".cache" / "lerobot-venv" / "bin" / "python"

_LOADER = r"""
import os, resource, sys, time, torch
kind, path, history, horizon = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
start = time.perf_counter()
collate = None
if kind.startswith("simreel"):
    from simreel.training import RecordingDataset
    ds = RecordingDataset(path, features=["obs", "actions"], history=history, horizon=horizon)
    collate = ds.collate if kind == "simreel" else None
    kind = "simreel"
elif kind == "lerobot":
    os.environ["HF_HUB_OFFLINE"] = "1"
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    dt = 1 / 20
    ds = LeRobotDataset("simreel/export", root=path, delta_timestamps={
        "observation.state": [k * dt for k in range(1 - history, 1)], "action": [k * dt for k in range(horizon)]})
else:
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset
    ds = ManiSkillTrajectoryDataset(path, load_count=-1, success_only=False, device=None)
built = time.perf_counter() - start
n = 0
for batch in torch.utils.data.DataLoader(ds, batch_size=64, shuffle=True, num_workers=0, collate_fn=collate):
    n += len(batch["actions" if kind == "simreel" else "action"])
took = time.perf_counter() - start
print(n, built, took, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def _loader(kind: str, path: Path, history: int = 1, horizon: int = 1) -> tuple[int, float, float, float]:
    from simreel.sim.render_device import lavapipe_icd_path

    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    icd = lavapipe_icd_path()
    if icd is not None:  # ManiSkill's dataset imports mani_skill (sapien), which wants a Vulkan driver
        env["VK_ICD_FILENAMES"] = str(icd)
    python = str(LEROBOT_PYTHON) if kind == "lerobot" else PYTHON
    done = subprocess.run([python, "-c", _LOADER, kind, str(path), str(history), str(horizon)], capture_output=True,
                          text=True, env=env, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} loader failed: {done.stderr.strip()[-800:]}")
    n, built, took, rss = done.stdout.split()[-4:]
    return int(n), float(built), float(took), float(rss)


LOADERS = (("ManiSkillTrajectoryDataset, single frames", "maniskill", 1, 1),
           ("LeRobotDataset, history 1, horizon 1", "lerobot", 1, 1),
           ("RecordingDataset, history 1, horizon 1", "simreel", 1, 1),
           ("LeRobotDataset, history 2, horizon 8", "lerobot", 2, 8),
           ("RecordingDataset, history 2, horizon 8", "simreel", 2, 8),
           ("RecordingDataset, h2 c8, default collate", "simreel-default", 2, 8))
"""(label, kind, history, horizon) of each loader measured."""


def _rates(loaders: Sequence[tuple[str, str, int, int]], path_of: Callable[[str], Path]) -> dict[str, float]:
    """Each loader's samples/s over the recording `path_of(kind)`, printed, and its ratio to ManiSkill's."""
    rates = {}
    for label, kind, history, horizon in loaders:
        n, built, took, _ = _loader(kind, path_of(kind), history, horizon)
        rates[label] = n / (took - built)
        print(f"  {label:44s} {rates[label]:9.0f} samples/s ({n} samples in {took - built:.2f} s; building it "
              f"{built:.2f} s, imports included)")
    base = rates["ManiSkillTrajectoryDataset, single frames"]
    print(f"  RecordingDataset single frames {rates['RecordingDataset, history 1, horizon 1'] / base:.2f}x "
          "ManiSkill's samples/s")
    return rates


def bench_loader(small: Path, large: Path, scale: int) -> None:
    print(f"DataLoader over state windows (batch 64, one process, one pass; {_episode_count(small)} episodes x "
          f"{STEPS} steps):")
    exported = small.with_name("state_lerobot")
    if LEROBOT_PYTHON.exists():
        subprocess.run([SIMREEL, "export", str(small), "--to", "lerobot", str(exported)], check=True,
                       capture_output=True)
    loaders = [loader for loader in LOADERS if loader[1] != "lerobot" or LEROBOT_PYTHON.exists()]
    if len(loaders) < len(LOADERS):
        print(f"  LeRobotDataset not run: no LeRobot venv at {LEROBOT_PYTHON} (make lerobot-env)")
    rates = _rates(loaders, lambda kind: exported if kind == "lerobot" else small)
    for window in ("history 1, horizon 1", "history 2, horizon 8"):
        if f"LeRobotDataset, {window}" in rates:
            print(f"  RecordingDataset {window}: {rates[f'RecordingDataset, {window}'] / rates[f'LeRobotDataset, {window}']:.2f}x "
                  "LeRobotDataset's samples/s")
    print(f"peak memory, a fresh process reading every sample once, {_episode_count(small)} vs "
          f"{_episode_count(large)} episodes ({scale}x):")
    for label, kind in (("RecordingDataset (history 2, horizon 8)", "simreel"),
                        ("ManiSkillTrajectoryDataset", "maniskill")):
        rss = [_loader(kind, path, 2 if kind == "simreel" else 1, 8 if kind == "simreel" else 1)[3]
               for path in (small, large)]
        print(f"  {label:44s} {rss[0]:7.0f} -> {rss[1]:7.0f} MiB ({rss[1] / rss[0]:.2f}x)")


RGB_LOADERS = (("ManiSkillTrajectoryDataset, single frames", "maniskill", 1, 1),
               ("RecordingDataset, history 1, horizon 1", "simreel", 1, 1),
               ("RecordingDataset, history 2, horizon 8", "simreel", 2, 8))
"""The loaders measured on camera windows (LeRobot's decoders do not run in its venv here: no torchcodec for the CPU
torch, and torchvision 0.28 has no VideoReader for its PyAV path)."""


def bench_rgb_loader(rec: Path) -> None:
    print(f"DataLoader over rgb windows (128x128 camera, batch 64, one process, one pass; {_episode_count(rec)} "
          f"episodes x {STEPS} steps; LeRobotDataset not run: its video decoders do not run in its venv here):")
    _rates(RGB_LOADERS, lambda kind: rec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=10, help="rgb episodes for the export (default 10)")
    parser.add_argument("--state-episodes", type=int, default=20, help="state episodes for the loader (default 20)")
    parser.add_argument("--scale", type=int, default=10, help="times more episodes for the memory figure")
    parser.add_argument("--rounds", type=int, default=3, help="export rounds of each tool (default 3)")
    parser.add_argument("--skip-export", action="store_true", help="only the loader and memory figures")
    parser.add_argument("--workers", type=lambda text: tuple(int(n) for n in text.split(",")), default=(1,),
                        metavar="N,N", help="simreel export --workers counts to time side by side (default 1)")
    parser.add_argument("--skip-loader", action="store_true", help="only the export figures")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if not args.skip_export:
            rec = _record(folder / "rgb.h5", args.episodes, "--obs-mode", "rgb")
            bench_export(folder, rec, args.rounds, args.workers)
        if args.skip_loader:
            return
        if not args.skip_export:
            bench_rgb_loader(rec)
        small = _record(folder / "state.h5", args.state_episodes)
        large = _record(folder / "state_x.h5", args.state_episodes * args.scale)
        bench_loader(small, large, args.scale)


if __name__ == "__main__":
    main()
