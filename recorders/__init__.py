"""simreel.recorders: the recording room — `RecordWrapper` (with its `RecordOptions`) and its step buffering.

Importing it prepares a machine for the user's own ``gym.make`` (`simreel.sim.make.prepare_plain_gym_make`):
the software Vulkan driver where `make setup` fetched one, and on a machine with no render device at all
the no-render layer, so ``gym.make(..., obs_mode="state", render_backend="none")`` builds.
"""

from simreel.recorders.record_wrapper import RecordOptions, RecordWrapper
from simreel.sim.make import prepare_plain_gym_make

__all__ = ["RecordWrapper", "RecordOptions"]

prepare_plain_gym_make()
