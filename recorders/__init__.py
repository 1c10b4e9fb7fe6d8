"""simreel.recorders: the recording room — `RecordWrapper` (with its `RecordOptions`) and its step buffering; and
`stopping_signals`, under which SIGTERM stops a recording as Ctrl-C does (``with stopping_signals(), RecordWrapper(...)
as env:`` commits the episodes cut short and closes the file; without it Python's default SIGTERM ends the process on
the spot, the file unclosed).

Importing `RecordWrapper` from it (``from simreel.recorders import RecordWrapper``) prepares a machine for the user's
own ``gym.make`` (`simreel.sim.make.prepare_plain_gym_make`): the software Vulkan driver where `make setup` fetched
one, and on a machine with no render device at all the no-render layer, so ``gym.make(..., obs_mode="state",
render_backend="none")`` builds. `RecordOptions` and `stopping_signals` alone import neither gymnasium nor a simulator
(``simreel record`` builds its parser from `RecordOptions`).
"""

from typing import Any

from simreel.io.durable import stopping_signals
from simreel.recorders.options import RecordOptions

__all__ = ["RecordWrapper", "RecordOptions", "stopping_signals"]


def __getattr__(name: str) -> Any:
    """`RecordWrapper`, imported (with gymnasium) when first asked for, the machine prepared first (PEP 562)."""
    if name != "RecordWrapper":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from simreel.sim.make import prepare_plain_gym_make

    prepare_plain_gym_make()
    from simreel.recorders.record_wrapper import RecordWrapper

    globals()["RecordWrapper"] = RecordWrapper
    return RecordWrapper


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
