"""A Ctrl-C that Python swallows (it landed in a finalizer) still stops the command at the next unit of work."""

from __future__ import annotations

import gc
import signal
import weakref

import pytest

from simreel.errors import Terminated
from simreel.io.durable import deferred_signals, raise_if_stopped, stopping_signals


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


def test_a_signal_held_while_the_block_fails_does_not_hide_its_error():
    """A Ctrl-C held during a commit or close that then fails: the failure (e.g. a full disk) is what is raised, so
    a command reports it (exit 2) instead of a bare interruption; the signal still stops the next unit of work."""
    with stopping_signals():
        with pytest.raises(OSError, match="No space left"), deferred_signals() as held:
            signal.raise_signal(signal.SIGINT)
            assert held == [signal.SIGINT]
            raise OSError(28, "No space left on device")
        with pytest.raises(KeyboardInterrupt):
            raise_if_stopped()


def test_a_signal_held_by_a_block_that_ends_well_is_raised_after_it():
    with stopping_signals(), pytest.raises(KeyboardInterrupt), deferred_signals():
        signal.raise_signal(signal.SIGINT)


def test_a_signal_swallowed_in_a_finalizer_prints_no_traceback_but_other_unraisable_errors_still_do():
    """Python reports an exception raised in a finalizer as "Exception ignored in ..." with a traceback on stderr:
    a Ctrl-C landing in one printed that before the command's own line ("simreel merge: interrupted")."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import gc, signal, sys, weakref
        from simreel.io.durable import raise_if_stopped, stopping_signals

        class Thing:
            pass

        def unraisable(exc):
            thing = Thing()
            weakref.finalize(thing, exc)
            del thing
            gc.collect()

        def value_error():
            raise ValueError("a finalizer's own bug")

        with stopping_signals():
            unraisable(lambda: signal.raise_signal(signal.SIGINT))
            unraisable(value_error)
            try:
                raise_if_stopped()
            except KeyboardInterrupt:
                print("stopped")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.stdout == "stopped\n"
    assert "KeyboardInterrupt" not in done.stderr
    assert "ValueError: a finalizer's own bug" in done.stderr


def test_a_block_inside_another_holds_through_the_outer_one():
    """Nested blocks (a recorder's reset runs a dozen) swap the handlers once: the inner one yields the outer's list
    of held signals, a signal it holds is handled when the outer block ends, and the handlers are back after."""
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt), deferred_signals() as outer:
        holding = signal.getsignal(signal.SIGINT)
        with deferred_signals() as inner:
            assert inner is outer
            assert signal.getsignal(signal.SIGINT) is holding
            signal.raise_signal(signal.SIGINT)
        assert outer == [signal.SIGINT]  # not raised yet: the outer block still holds it
    assert signal.getsignal(signal.SIGINT) is before


def test_an_error_inside_a_nested_block_wins_and_the_signal_it_held_still_stops_the_next_unit():
    with stopping_signals():
        with pytest.raises(OSError, match="No space left"), deferred_signals(), deferred_signals():
            signal.raise_signal(signal.SIGTERM)
            raise OSError(28, "No space left on device")
        with pytest.raises(Terminated):
            raise_if_stopped()


def test_a_nested_block_that_fails_notes_the_signals_that_came_during_it_and_the_outer_block_goes_on():
    """As a block of its own did: its error wins, and what came during it is left for `raise_if_stopped` (a cleanup
    that swallows the error must not then be interrupted by it); a signal held before it stays the outer's."""
    with stopping_signals():
        with pytest.raises(KeyboardInterrupt), deferred_signals() as outer:
            signal.raise_signal(signal.SIGINT)
            with pytest.raises(OSError), deferred_signals():
                signal.raise_signal(signal.SIGTERM)
                raise OSError(28, "No space left on device")
            assert outer == [signal.SIGINT]  # the SIGTERM is noted, not the outer block's to raise
        with pytest.raises(Terminated):
            raise_if_stopped()
