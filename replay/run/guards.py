"""What the engine wraps its env's calls in: the garbage collector kept off the objects alive before a build or a
close (`older_objects_unscanned`), and the user's task code's errors raised as `TaskCodeError` (`task_code_errors`)."""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

from simreel.errors import SimreelError

__all__ = ["older_objects_unscanned", "task_code_errors"]


@contextlib.contextmanager
def older_objects_unscanned() -> Iterator[None]:
    """ManiSkill collects garbage (``gc.collect()``) as it builds and as it clears a scene: 0.2 s each in a process
    holding torch and a replay's objects, two thirds of the time to verify one short episode. In the block the objects
    alive before it are out of the collector's sight (``gc.freeze``), and back in it after: garbage among them is
    collected later, as any is."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@contextlib.contextmanager
def task_code_errors() -> Iterator[None]:
    """Raise what the user's task code raised in the block as `TaskCodeError` (`task_code_error`): that episode's
    verdict is then an error naming the task's line, and a dataset run goes on with the next episode."""
    from simreel.sim.user_code import task_code_error

    try:
        yield
    except SimreelError:
        raise
    except Exception as exc:
        error = task_code_error(exc)
        if error is None:
            raise
        raise error from exc
