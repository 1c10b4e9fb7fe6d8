"""How far a correct control-mode conversion is from the original, per step: the measurements behind the default
tracking tolerances of `simreel.replay.convert.tracking`.

Records pd_joint_pos demos with ManiSkill's own RecordEpisode (the test fixtures' paths: an IK-planned grasp for
PickCube, smooth joint paths for StackCube, PegInsertionSide and SimreelHeteroDrawer), converts them to
pd_joint_delta_pos and pd_ee_delta_pose with `simreel convert`, and prints the largest error of each tracked group
over the episodes whose converted actions were never clipped (where one step cannot reach the recorded target,
the conversion is expected to fall behind), next to the defaults.

    .venv/bin/python benchmarks/measure_tracking.py                 # 8 episodes of 60 steps per task
    .venv/bin/python benchmarks/measure_tracking.py --episodes 16 --steps 60
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

from demo_files import demo_arguments, demo_recorder

TASKS = {"PickCube-v1": "pick", "StackCube-v1": "smooth", "PegInsertionSide-v1": "smooth",
         "SimreelHeteroDrawer-v1": "smooth"}
MODES = ("pd_joint_delta_pos", "pd_ee_delta_pose")


def _group(key: str) -> str | None:
    """The tolerance group of a tracked key."""
    if key == "success":
        return "success"
    part = key.rsplit("[", 1)[-1].rstrip("]")
    if key.startswith("command/"):
        return "cmd_pos" if part == "p" else "cmd_rot"
    if key.startswith("ee/"):
        return "ee_pos" if part == "p" else "ee_rot"
    return {"p": "obj_pos", "root_p": "obj_pos", "q": "obj_rot", "root_q": "obj_rot", "qpos": "obj_qpos"}.get(part)


def main() -> int:
    args = demo_arguments(__doc__, episodes=8, steps=60)
    record_maniskill = demo_recorder()

    import simreel.tasks  # noqa: F401  (registers SimreelHeteroDrawer-v1 for ManiSkill's gym.make)
    from simreel.replay.convert.convert import convert_recording
    from simreel.replay.convert.tracking import DEFAULT_TRACKING_TOLERANCES

    tmp = Path(tempfile.mkdtemp(prefix="measure_tracking_"))
    try:
        for mode in MODES:
            worst: dict[str, tuple[float, str]] = {}
            skipped = []
            for env_id, path in TASKS.items():
                src = tmp / f"{env_id}.h5"
                if not src.exists():
                    record_maniskill(tmp, env_id, name=env_id, episodes=args.episodes, steps=args.steps, path=path)
                report = convert_recording(src, tmp / f"{env_id}.{mode}.h5", control_mode=mode, overwrite=True)
                for e in report.episodes:
                    if any("was clipped" in n for n in e.notes):
                        skipped.append(f"{env_id}#{e.index}")
                        continue
                    for key, err in e.max_abs_error.items():
                        g = _group(key)
                        if g is not None and err >= worst.get(g, (-1.0, ""))[0]:
                            worst[g] = (err, f"{env_id}#{e.index}")
            print(f"{mode}: {len(TASKS)} tasks x {args.episodes} episodes x {args.steps} steps; clipped episodes left "
                  f"out: {', '.join(skipped) or 'none'}")
            for g, tol in DEFAULT_TRACKING_TOLERANCES.items():
                err, where = worst.get(g, (0.0, "-"))
                print(f"  {g:<9} largest {err:10.3g} ({where:<26}) default tolerance {tol:g} ({tol / err:.0f}x)"
                      if err else f"  {g:<9} largest {0:10.3g} {'':28} default tolerance {tol:g}")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
