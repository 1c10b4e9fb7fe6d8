"""The work list of a replay run (`simreel.replay.run.worklist`): one item per episode of every input, ordered so a
worker rebuilds its env only when the env key changes; unreadable files of a folder kept with their reason;
finished episodes of a resumed run left out."""

from __future__ import annotations

import shutil

import pytest

from simreel.errors import RecordingFileError, UsageError
from simreel.replay.run.worklist import build_worklist


@pytest.fixture(scope="module")
def dataset(record, tmp_path_factory):
    """data/: two PickCube recordings, one StackCube between them (by name), and a file that is no recording."""
    root = tmp_path_factory.mktemp("dataset")
    data = root / "data"
    data.mkdir()
    shutil.copy(record("PickCube-v1", 2, 6), data / "a_pick.h5")
    shutil.copy(record("StackCube-v1", 1, 5), data / "b_stack.h5")
    shutil.copy(record("PickCube-v1", 1, 6, "--seed", "9"), data / "c_pick.h5")
    (data / "d_junk.h5").write_text("not a recording")
    return data


def test_items_are_grouped_by_env_key_then_input_order(dataset):
    work = build_worklist([dataset])
    names = [(p.split("/")[-1], i, s) for p, i, s in ((w.path, w.index, w.steps) for w in work.items)]
    keys = [w.key for w in work.items]
    assert keys == sorted(keys) and len(set(keys)) == 2
    pick = [n for n in names if "pick" in n[0]]
    assert pick == [("a_pick.h5", 0, 6), ("a_pick.h5", 1, 6), ("c_pick.h5", 0, 6)]  # one key, input order
    assert ("b_stack.h5", 0, 5) in names
    junk = [f for f in work.files if f.error is not None]
    assert [f.path.split("/")[-1] for f in junk] == ["d_junk.h5"] and "neither an HDF5 nor an MCAP" in junk[0].error
    assert [f.path.split("/")[-1] for f in work.readable] == ["a_pick.h5", "b_stack.h5", "c_pick.h5"]


def test_a_file_named_explicitly_that_cannot_be_read_is_bad_input(dataset):
    with pytest.raises(RecordingFileError, match="neither an HDF5 nor an MCAP"):
        build_worklist([dataset / "a_pick.h5", dataset / "d_junk.h5"])


def test_episodes_asked_for_come_in_recorded_order_and_a_missing_one_is_named(dataset):
    work = build_worklist([dataset / "a_pick.h5"], episodes=[1, 0, 1])
    assert [w.index for w in work.items] == [0, 1]  # recorded order: no scene history replayed twice
    with pytest.raises(RecordingFileError, match=r"no episode 5 \(episodes: 0, 1\)"):
        build_worklist([dataset / "a_pick.h5"], episodes=[5])


def test_a_resumed_run_leaves_out_what_is_done(dataset):
    a = str(dataset / "a_pick.h5")
    work = build_worklist([dataset], done=[(a, 0), (a, 1)])
    assert work.skipped == 2 and all(w.path != a for w in work.items) and len(work.items) == 2


def test_modes_that_restore_states_refuse_a_file_without_them(tmp_path, record):
    no_states = tmp_path / "no_states.h5"
    _without_states(record("PickCube-v1", 2, 6), no_states)
    with pytest.raises(UsageError, match="holds no env_states .*--resync restores recorded states; replay it with"):
        build_worklist([no_states], restores="--resync")
    assert len(build_worklist([no_states]).items) == 2


def _without_states(src, dst) -> None:
    """A copy of `src` whose metadata lists no env_states (what a file recorded without them says)."""
    import json

    import h5py

    from simreel.formats.hdf5.layout import META_ATTR

    shutil.copy(src, dst)
    with h5py.File(dst, "r+") as f:
        meta = json.loads(f.attrs[META_ATTR])
        meta["state_layout"] = {}
        f.attrs[META_ATTR] = json.dumps(meta)
        for name in f:
            if name.startswith("traj_"):
                del f[name]["env_states"]
