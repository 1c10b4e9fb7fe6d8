"""The cost of verifying one late episode against verifying every episode, in one run on one recording.

Usage: python benchmarks/bench_history.py [--env PickCube-v1] [--control-mode pd_joint_delta_pos] [--episodes 500]
                                          [--steps 10] [--unseeded] [--keep PATH] [--each]

Records `--episodes` episodes of `--steps` random actions (torch's generator seeded 0) with RecordWrapper's default
options, each reset with seed e (`--unseeded`: only the first, as RL rollouts reset), then times, in this process,
`verify_recording(path, episodes=[last])` and `verify_recording(path)` (mode actions, one worker each). PhysX's CPU
results depend on what the scene ran since it was built: the last episode is replayed after only the last step of the
one before it (from its recorded state), kept if exact, else after its whole history; the script prints which, the
two times and their ratio. Target (issue 44): the last episode's time at most 5% of the whole run's.

`--each` instead replays every episode from the third on alone, last first, in one worker (each after only the last
step of the one before it, as `--episodes K` does), and counts those kept after that step (exact) and those replayed
again after their whole history, with their verdicts.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def record(path: Path, env_id: str, control_mode: str, shape: tuple[int, int], *, unseeded: bool) -> Path:
    import torch

    from simreel.recorders import RecordWrapper
    from simreel.sim.make import make_env

    episodes, steps = shape
    rec = RecordWrapper(make_env(env_id, render_backend="none", control_mode=control_mode), path, overwrite=True)
    torch.manual_seed(0)
    for e in range(episodes):
        rec.reset() if unseeded and e else rec.reset(seed=e)
        for _ in range(steps):
            rec.step(torch.rand(rec.action_space.shape) * 2 - 1)
    rec.close()
    return path


def timed(path: Path, **options) -> tuple[float, list]:
    from simreel.replay import verify_recording

    start = time.perf_counter()
    report = verify_recording(path, **options)
    return time.perf_counter() - start, report.episodes


def each_alone(path: Path) -> None:
    """`--each`: every episode from index 2 on replayed alone, last first, in one worker."""
    from collections import Counter

    from simreel.formats import open_reader
    from simreel.model.components import Tolerances
    from simreel.replay.run.job import ReplayJob
    from simreel.replay.run.workers import ReplayWorker
    from simreel.replay.run.worklist import WorkItem, env_key

    with open_reader(path) as reader:
        key, count = env_key(reader.meta), len(reader.episodes)
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    kept, whole = Counter(), Counter()
    try:
        for index in range(count - 1, 1, -1):
            report = worker.run(WorkItem(key, str(path), index)).report
            (kept if report.history.steps == 1 else whole)[report.verdict] += 1
    finally:
        worker.close()
    print(f"{count - 2} episodes alone: kept after the last step before it {sum(kept.values())} {dict(kept)}; "
          f"replayed again after their whole history {sum(whole.values())} {dict(whole)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="PickCube-v1")
    ap.add_argument("--control-mode", default="pd_joint_delta_pos")
    ap.add_argument("--episodes", type=int, default=500)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--unseeded", action="store_true", help="reset with a seed only once, as RL rollouts do")
    ap.add_argument("--keep", type=Path, help="write the recording here (default: a temporary folder)")
    ap.add_argument("--each", action="store_true", help="replay each episode alone instead, and count how")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / "history.h5"
        start = time.perf_counter()
        record(path, args.env, args.control_mode, (args.episodes, args.steps), unseeded=args.unseeded)
        print(f"recorded {args.episodes} x {args.steps} steps of {args.env} ({args.control_mode}) in "
              f"{time.perf_counter() - start:.1f} s")
        if args.each:
            each_alone(path)
            return
        last = args.episodes - 1
        one, (episode,) = timed(path, episodes=[last])
        every, episodes = timed(path)
        exact = sum(e.verdict == "exact" for e in episodes)
        print(f"last episode ({last}): {one:.2f} s, {episode.verdict}; history: {episode.history.describe()}")
        print(f"all {len(episodes)} episodes: {every:.2f} s, {exact} exact")
        print(f"ratio: {one / every:.2%} (target <= 5%)")


if __name__ == "__main__":
    main()
