"""simreel.recorders: the recording room — `RecordWrapper` (with its `RecordOptions`) and its step buffering; and
`stopping_signals`, under which SIGTERM stops a recording as Ctrl-C does (``with stopping_signals(), RecordWrapper(...)
as env:`` commits the episodes cut short and closes the file; without it Python's default SIGTERM ends the process on
the spot, the file unclosed).

Importing it prepares a machine for the user's own ``gym.make`` (`simreel.sim.make.prepare_plain_gym_make`):
the software Vulkan driver where `make setup` fetched one, and on a machine with no render device at all
the no-render layer, so ``gym.make(..., obs_mode="state", render_backend="none")`` builds.
"""

from simreel.io.durable import stopping_signals
from simreel.recorders.record_wrapper import RecordOptions, RecordWrapper
from simreel.sim.make import prepare_plain_gym_make

__all__ = ["RecordWrapper", "RecordOptions", "stopping_signals"]

prepare_plain_gym_make()
