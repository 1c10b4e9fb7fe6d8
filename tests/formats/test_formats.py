"""`simreel.formats` itself: what it answers for every format (output checks, removal, pose default, row 0)."""

from __future__ import annotations

import pytest

from simreel.errors import UsageError
from simreel.formats import check_writable, records_poses_by_default


@pytest.mark.parametrize(
    ("name", "poses"), [("a.mcap", True), ("a.MCAP", True), ("a.h5", False), ("dir/a.hdf5", False)]
)
def test_records_poses_by_default_only_for_mcap(name, poses):
    assert records_poses_by_default(name) is poses


def test_records_poses_by_default_refuses_an_unknown_suffix():
    with pytest.raises(UsageError, match=r"a\.txt: unknown recording suffix '\.txt'"):
        records_poses_by_default("a.txt")


@pytest.mark.parametrize(
    ("target", "make", "overwrite", "message"),
    [
        ("out.mcap", None, False, None),
        ("out.h5", None, False, None),
        ("out.txt", None, False, "out.txt: unknown recording suffix '.txt'"),
        ("missing/out.mcap", None, True, "cannot write {tmp}/missing/out.mcap: folder {tmp}/missing does not exist"),
        ("out.mcap", "out.mcap", False, "{tmp}/out.mcap already exists; pass --overwrite to replace it"),
        ("out.mcap", "out.mcap", True, None),
        ("out.h5", "out.json", False,
         "{tmp}/out.json already exists and writing out.h5 would replace it; pass --overwrite to replace it"),
        ("out.h5", "out.json", True, None),
    ],
)
def test_check_writable_raises_what_the_writer_would_and_touches_nothing(tmp_path, target, make, overwrite, message):
    if make:
        (tmp_path / make).write_text("mine")
    before = sorted(tmp_path.iterdir())
    if message is None:
        check_writable(tmp_path / target, overwrite=overwrite)
    else:
        with pytest.raises(UsageError) as err:
            check_writable(tmp_path / target, overwrite=overwrite)
        assert message.format(tmp=tmp_path) in str(err.value)
    assert sorted(tmp_path.iterdir()) == before
    if make:
        assert (tmp_path / make).read_text() == "mine"
