"""A Ctrl-C that Python swallows (it landed in a finalizer) still stops the command at the next unit of work."""

from __future__ import annotations

import gc
import signal
import weakref

import pytest

from simreel.errors import Terminated
from simreel.formats.durable import raise_if_stopped, stopping_signals


class _Thing:
    pass


def _signal_inside_a_finalizer(signum: int) -> None:
    thing = _Thing()
    weakref.finalize(thing, signal.raise_signal, signum)  # the handler's exception is raised in the finalizer
    del thing
    gc.collect()


@pytest.mark.parametrize(("signum", "exception"), [(signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, Terminated)])
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_signal_swallowed_in_a_finalizer_is_raised_again(signum, exception):
    before = signal.getsignal(signum)
    with stopping_signals():
        _signal_inside_a_finalizer(signum)  # Python reports the exception as unraisable and goes on
        with pytest.raises(exception):
            raise_if_stopped()
    assert signal.getsignal(signum) is before
    raise_if_stopped()  # outside, nothing is pending


def test_without_a_signal_nothing_is_raised():
    with stopping_signals():
        raise_if_stopped()
