"""Determinism of replays on the CPU sim, measured: is a replay bit-exact, and where is it not, by how much?

Usage: python benchmarks/determinism.py [--episodes 4] [--steps 50] [--tasks PickCube-v1,...]

Each task is recorded in this process (random actions for ManiSkill's tasks, the scripted policy for simreel's,
seeds 0..N-1), then replayed in actions mode and compared with the recording, leaf by leaf, in five ways:

- same process: replayed in the process that recorded it (a new env);
- fresh process: ``simreel replay`` in a new Python process;
- worker process: ``--workers 2``: episodes split between this process and a spawned worker;
- episode order: the episodes replayed last to first (heterogeneous tasks rebuild their scenes in another order);
- restore-then-replay: the recorded state restored in mid-episode and the rest replayed (``--resync K``, K half
  the shortest episode: restored before every K-th action).

Printed per task and scenario: how many episodes were bit-exact, the largest error per kind of state component
(positions and joint positions, rotations, velocities, other state) and over everything compared (rewards, info,
contact forces too). 0 means equal to the last bit. CPU vs GPU and different ``num_envs`` need the GPU sim; without a CUDA device they are reported as
not measured.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DEFAULT_TASKS = ("PickCube-v1", "StackCube-v1", "SimreelLiftCube-v1", "SimreelHeteroDrawer-v1")
SCENARIOS = ("same process", "fresh process", "worker process", "episode order", "restore-then-replay")


def _record(env_id: str, path: Path, episodes: int, steps: int) -> None:
    from simreel.cli.main import main

    policy = ["--policy", "scripted"] if env_id.startswith("Simreel") else []
    args = ["record", env_id, "-o", str(path), "-n", str(episodes), "--max-steps", str(steps), "--seed", "0",
            "--render-backend", "none", "-q", *policy]
    if main(args) != 0:
        raise SystemExit(f"recording {env_id} failed")


_KINDS = {"position": ("[p]", "[root_p]", "[qpos]"), "rotation": ("[q]", "[root_q]"),
          "velocity": ("[v]", "[w]", "[root_v]", "[root_w]", "[qvel]")}
"""State components by kind, by the name `simreel.verdicts.compare` gives them; everything else of the state (task state,
controller targets) is "other"."""


def _kind(key: str) -> str:
    return next((kind for kind, ends in _KINDS.items() if key.endswith(ends)), "other")


def _summary(episodes: list[dict]) -> dict:
    """Largest error per kind of state component and over everything compared, and the bit-exact episodes."""
    out = {kind: 0.0 for kind in (*_KINDS, "other", "all")}
    for e in episodes:
        for key, value in e["max_abs_error"].items():
            value = float(value)  # JSON writes inf as "inf"
            out["all"] = max(out["all"], value)
            if key.startswith("env_states/"):
                kind = _kind(key)
                out[kind] = max(out[kind], value)
    out["exact"] = sum(e["verdict"] == "exact" for e in episodes)
    out["episodes"] = len(episodes)
    return out


def _in_process(path: Path, **options) -> dict:
    from simreel.replay import verify_recording

    return _summary(verify_recording(path, **options).to_json()["episodes"])


def _fresh_process(path: Path, folder: Path) -> dict:
    report = folder / f"{path.stem}.report.json"
    cmd = [sys.executable, "-m", "simreel", "replay", str(path), "--report", str(report), "--overwrite", "-q"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)} failed: {done.stderr.strip()}")
    return _summary(json.loads(report.read_text())["episodes"])


def measure(env_id: str, folder: Path, episodes: int, steps: int) -> dict[str, dict]:
    from simreel.formats import open_reader

    path = folder / f"{env_id}.h5"
    _record(env_id, path, episodes, steps)
    with open_reader(path) as r:
        shortest = min(m.length for m in r.episodes)
    restore_at = max(1, shortest // 2)  # mid-episode of the shortest episode (the scripted ones end on success)
    out = {
        "same process": _in_process(path),
        "fresh process": _fresh_process(path, folder),
        "worker process": _in_process(path, workers=2),
        "episode order": _in_process(path, episodes=tuple(reversed(range(episodes)))),
        "restore-then-replay": _in_process(path, resync=restore_at),
    }
    out["restore-then-replay"]["resync"] = restore_at
    return out


def _number(x: float) -> str:
    return "0" if x == 0 else f"{x:.2g}"


def _row(task: str, scenario: str, m: dict) -> str:
    name = scenario + (f" (every {m['resync']})" if "resync" in m else "")
    cells = [f"{m['exact']}/{m['episodes']}"] + [_number(m[k]) for k in (*_KINDS, "other", "all")]
    return f"{task:<24}{name:<30}" + "".join(f"{c:>11}" for c in cells)


def _gpu_line() -> str:
    try:
        import torch

        cuda = torch.cuda.is_available()
    except Exception:  # noqa: BLE001 - no torch build with CUDA: not measured
        cuda = False
    if not cuda:
        return "CPU vs GPU sim, different num_envs: not measured (no CUDA device on this machine)"
    return "CPU vs GPU sim, different num_envs: a CUDA device is present, but this script measures the CPU sim only"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--tasks", default=",".join(DEFAULT_TASKS))
    ap.add_argument("--json", default=None, help="also write the measurements here")
    args = ap.parse_args()
    tasks = [t for t in args.tasks.split(",") if t]
    folder = Path(tempfile.mkdtemp())
    t0 = time.perf_counter()
    results = {task: measure(task, folder, args.episodes, args.steps) for task in tasks}
    print(f"replay equality on the CPU sim (physx_cpu), actions mode, {args.episodes} episodes × up to {args.steps} "
          f"steps per task ({time.perf_counter() - t0:.0f} s); largest error per kind of state component (m, rad, "
          "m/s, rad/s; other: task state, controller targets) and over everything compared (rewards, info, contacts)")
    heads = ["exact", *_KINDS, "other", "all"]
    print(f"{'task':<24}{'scenario':<30}" + "".join(f"{h:>11}" for h in heads))
    for task in tasks:
        for scenario in SCENARIOS:
            print(_row(task, scenario, results[task][scenario]))
    print(_gpu_line())
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    worst = max((results[t][s]["all"] for t in tasks for s in SCENARIOS[:4]), default=0.0)
    if not math.isfinite(worst):
        raise SystemExit("a replay produced a non-finite error")


if __name__ == "__main__":
    main()
