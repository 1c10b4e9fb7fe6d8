"""`BlockCache` keeps at most `OPEN_EPISODES` episodes open in a process (each holds its datasets' handles and their
chunk caches), so a pass over a set of many episodes does not grow with it, and gives the same rows after reopening
one it let go."""

from __future__ import annotations

from simreel.training import RecordingDataset
from simreel.training.blocks import OPEN_EPISODES


def test_a_pass_over_many_episodes_keeps_few_open_and_reads_the_same_rows(record):
    rec = record("PickCube-v1", OPEN_EPISODES + 4, 3)
    with RecordingDataset(rec, features=["env_states/actors/cube", "actions"], history=2, horizon=2) as ds:
        assert len(ds.episodes) == OPEN_EPISODES + 4
        first = [ds[k] for k in range(len(ds))]
        assert len(ds.cache._episodes) == OPEN_EPISODES
        assert (ds.episodes[0].path, ds.episodes[0].index) not in ds.cache._episodes  # the first one was let go
        assert (ds.episodes[-1].path, ds.episodes[-1].index) in ds.cache._episodes
        ds.cache._blocks.clear()  # the rows must come from the files again
        again = [ds[k] for k in range(len(ds))]
    assert all(a[n].tobytes() == b[n].tobytes() for a, b in zip(first, again, strict=True)
               for n in ("env_states/actors/cube", "actions"))
