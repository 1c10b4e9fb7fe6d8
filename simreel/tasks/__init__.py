"""simreel's example tasks, registered with ManiSkill when this package is imported.

- ``SimreelLiftCube-v1``: lift a cube to a per-episode target height (custom state ``goal_height``).
- ``SimreelLiftCubeLeaky-v1``: the same with the height left out of the state dict (an audit test bed).
- ``SimreelLiftCubeStageLeaky-v1``: a stage latched after the lift left out of it (a leak only a trajectory audit finds).
- ``SimreelHeteroPick-v1``: pick up a procedurally generated object, a different one in each sub-scene.
- ``SimreelHeteroDrawer-v1``: pull open a drawer of a procedurally built cabinet with 1-3 joints.

All default to the ``pd_ee_delta_pos`` control mode; `simreel.tasks.policies` has a scripted policy for
each. Importing this package imports mani_skill.
"""

from __future__ import annotations

from simreel.tasks.hetero_drawer import HeteroDrawerEnv
from simreel.tasks.hetero_pick import HeteroPickEnv
from simreel.tasks.lift_cube import LiftCubeEnv, LiftCubeLeakyEnv, LiftCubeStageLeakyEnv

TASK_IDS = (
    "SimreelLiftCube-v1",
    "SimreelLiftCubeLeaky-v1",
    "SimreelLiftCubeStageLeaky-v1",
    "SimreelHeteroPick-v1",
    "SimreelHeteroDrawer-v1",
)
"""Every env id this package registers."""

__all__ = ["TASK_IDS", "HeteroDrawerEnv", "HeteroPickEnv", "LiftCubeEnv", "LiftCubeLeakyEnv", "LiftCubeStageLeakyEnv"]
