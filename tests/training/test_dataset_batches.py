"""`RecordingDataset.__getitems__` (what a DataLoader asks for, a batch at a time) gives exactly the samples
`__getitem__` gives one by one, pads and control-mode action padding included, on shuffled batches whose windows
cross episode starts and ends and block boundaries; `RecordingDataset.collate` makes the tensors torch's default
collate makes, with 0 and 2 DataLoader workers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simreel.training import RecordingDataset
from simreel.training.blocks import BlockCache

FEATURES = {"pick": ["obs", "env_states/actors/cube", "actions", "rewards", "success"],
            "stack": ["env_states/articulations/panda_wristcam", "actions", "rewards", "info"]}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        type(a[k]) is type(b[k]) and (a[k] == b[k] if isinstance(a[k], int) else
                                      a[k].dtype == b[k].dtype and a[k].shape == b[k].shape
                                      and a[k].tobytes() == b[k].tobytes()) for k in a)


@pytest.mark.parametrize("task", sorted(FEATURES))
def test_a_shuffled_batch_equals_the_samples_one_by_one(three_tasks, task):
    options = dict(features=FEATURES[task], history=3, horizon=6)
    with RecordingDataset(three_tasks[task], **options) as batched, \
            RecordingDataset(three_tasks[task], **options) as single:
        batched.cache = BlockCache(batched.fields, rows=4)  # windows cross block boundaries
        order = np.random.default_rng(3).permutation(len(batched))
        for start in range(0, len(order), 17):
            got = batched.__getitems__(order[start:start + 17].tolist())
            want = [single[int(k)] for k in order[start:start + 17]]
            assert len(got) == len(want) and all(_same(g, w) for g, w in zip(got, want, strict=True))
        every = batched.batch(list(range(len(batched))))
        state = next(f.name for f in batched.fields if f.per_state)
        assert every["actions_is_pad"].any() and every[f"{state}_is_pad"].any()  # the batches held windows past the ends and before the starts


def test_a_bad_sample_number_in_a_batch_is_an_index_error(three_tasks):
    with RecordingDataset(three_tasks["stack"], features=["actions"]) as ds:
        with pytest.raises(IndexError, match=f"sample {len(ds)}: the set has {len(ds)} samples"):
            ds.__getitems__([0, len(ds)])
        assert _same(ds.__getitems__([-1])[0], ds[len(ds) - 1])


@pytest.mark.parametrize("workers", [0, 2])
def test_collate_makes_the_default_collates_tensors(three_tasks, workers):
    with RecordingDataset(three_tasks["pick"], features=FEATURES["pick"], history=2, horizon=8) as ds:
        order = np.random.default_rng(1).permutation(len(ds)).tolist()  # shuffled, in an order the test knows
        loader = torch.utils.data.DataLoader(ds, batch_size=16, num_workers=workers, sampler=order,
                                             collate_fn=ds.collate)
        batches = list(loader)
        for k, batch in enumerate(batches):
            want = torch.utils.data.default_collate([ds[i] for i in order[16 * k:16 * (k + 1)]])
            assert batch.keys() == want.keys()
            for key, value in want.items():
                assert batch[key].dtype == value.dtype and torch.equal(batch[key], value), key
