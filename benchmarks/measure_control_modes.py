"""Which control modes a pd_joint_pos demo converts to, verified, on two robots: the verdict counts behind the table
of docs/conversion.md.

Records pd_joint_pos demos of PickCube-v1 with ManiSkill's own RecordEpisode for the Panda (the test fixtures'
grasp-and-lift planned with IK) and for Fetch (a smooth arm swing, its torso and mobile base holding still; the
other robots of PickCube, xarm6_robotiq and widowxai, need asset downloads, and so100 has no end-effector modes),
converts them to every mode simreel converts pd_joint_pos to (`simreel.replay.convert.control.SUPPORTED`) with the
default tolerances, writing every episode (``keep="all"``), and prints a markdown table of the verdicts.

    .venv/bin/python benchmarks/measure_control_modes.py                 # 4 episodes of 45 steps per robot
    .venv/bin/python benchmarks/measure_control_modes.py --episodes 8 --steps 60
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from collections import Counter
from pathlib import Path

from demo_files import demo_arguments, demo_recorder

ROBOTS = {"panda": ("pick", {}), "fetch": ("arm", {"robot_uids": "fetch"})}
"""Robot → (the demo path of `tests/support/maniskill_files.record_maniskill`, PickCube-v1's env kwargs)."""


def main() -> int:
    args = demo_arguments(__doc__, episodes=4, steps=45)
    record_maniskill = demo_recorder()

    from simreel.replay.convert.control import SUPPORTED
    from simreel.replay.convert.convert import convert_recording

    tmp = Path(tempfile.mkdtemp(prefix="measure_control_modes_"))
    try:
        sources = {robot: record_maniskill(tmp, "PickCube-v1", name=robot, episodes=args.episodes, steps=args.steps,
                                           path=path, env_kwargs=kwargs) for robot, (path, kwargs) in ROBOTS.items()}
        print(f"PickCube-v1, {args.episodes} episodes x {args.steps} steps per robot, default tolerances\n")
        print("| pd_joint_pos -> | " + " | ".join(ROBOTS) + " |")
        print("|---|" + "---|" * len(ROBOTS))
        for mode in SUPPORTED["pd_joint_pos"]:
            cells = []
            for robot, src in sources.items():
                report = convert_recording(src, tmp / f"{robot}.{mode}.h5", control_mode=mode, keep="all")
                counts = Counter(e.verdict for e in report.episodes)
                cells.append(", ".join(f"{n} {verdict}" for verdict, n in sorted(counts.items())))
            print(f"| `{mode}` | " + " | ".join(cells) + " |")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
