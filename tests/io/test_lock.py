"""`simreel.io.lock`: a writer's lock on a new recording file refuses a file that is there, saying how to replace
it from the command line and from Python."""

from __future__ import annotations

import pytest

from simreel.errors import UsageError
from simreel.io.lock import WriterLock, being_written


def test_a_new_file_that_is_there_is_refused_naming_both_ways_to_replace_it(tmp_path):
    """The message named only --overwrite, which a Python script (RecordWrapper) does not have."""
    path = tmp_path / "r.mcap"
    lock = WriterLock.acquire(path, create=True)
    try:
        assert being_written(path)
        with pytest.raises(UsageError) as refused:
            WriterLock.acquire(path, create=True)
        assert str(refused.value) == f"{path} already exists; pass --overwrite to replace it (overwrite=True from Python)"
    finally:
        lock.release()
    assert not being_written(path)
