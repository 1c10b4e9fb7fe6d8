"""Normalization statistics in one streaming pass, equal to numpy's over every row; saved and loaded; and a small
policy trained on a `RecordingDataset` with them, its loss falling (CPU, a few hundred steps)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.training import FeatureStats, RecordingDataset, compute_stats


def test_streamed_statistics_equal_numpys_over_every_row(three_tasks):
    with RecordingDataset(three_tasks["pick"], features=["obs", "actions", "success"]) as ds:
        ds.cache.rows = 7  # several blocks an episode: the merge is exercised
        stats = compute_stats(ds)
    with open_reader(three_tasks["pick"]) as reader:
        episodes = [reader.read_episode(m.index).fields() for m in reader.episodes]
    for name in ("obs/state", "actions", "success"):
        rows = np.concatenate([e[name] for e in episodes]).astype(np.float64)
        got = stats.features[name]
        assert got["count"] == len(rows)
        np.testing.assert_allclose(got["mean"], rows.mean(axis=0), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got["std"], rows.std(axis=0), rtol=1e-9, atol=1e-12)
        assert got["min"] == rows.min(axis=0).tolist() and got["max"] == rows.max(axis=0).tolist()
    assert stats.features["obs/state"]["count"] == 3 * 31  # T + 1 states an episode
    assert [e["index"] for e in stats.episodes] == [0, 1, 2]


def test_statistics_are_saved_and_loaded(three_tasks, tmp_path):
    with RecordingDataset(three_tasks["stack"], features=["actions"]) as ds:
        stats = compute_stats(ds)
    path = stats.save(tmp_path / "stats.json")
    assert FeatureStats.load(path) == stats
    with pytest.raises(UsageError, match="already exists"):
        stats.save(path)
    stats.save(path, overwrite=True)
    (tmp_path / "other.json").write_text('{"features": {"actions": {"mean": []}}}')
    with pytest.raises(UsageError, match=re.escape("other.json: not a statistics file written by FeatureStats.save")):
        FeatureStats.load(tmp_path / "other.json")
    x = np.asarray(stats.features["actions"]["mean"]) + np.asarray(stats.features["actions"]["std"])
    np.testing.assert_allclose(stats.normalize("actions", x), 1.0, rtol=1e-6)
    np.testing.assert_allclose(stats.unnormalize("actions", stats.normalize("actions", x)), x)


@pytest.fixture
def one_thread():
    """torch on one thread: a tiny MLP's steps are 30x slower where its threads contend for two busy cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_a_small_policy_trains_on_the_dataset(three_tasks, one_thread):
    torch.manual_seed(0)
    ds = RecordingDataset(three_tasks["pick"], features=["obs/state", "actions"], history=2, horizon=4)
    stats = compute_stats(ds)
    loader = torch.utils.data.DataLoader(ds, batch_size=32, shuffle=True)
    obs_dim, act_dim = 2 * 42, 4 * 8
    policy = torch.nn.Sequential(torch.nn.Linear(obs_dim, 128), torch.nn.ReLU(), torch.nn.Linear(128, act_dim))
    optimizer = torch.optim.Adam(policy.parameters(), lr=3e-3)
    losses = []
    while len(losses) < 300:
        for batch in loader:
            obs = stats.normalize("obs/state", batch["obs/state"].double()).float().flatten(1)
            target = stats.normalize("actions", batch["actions"].double()).float().flatten(1)
            loss = torch.nn.functional.mse_loss(policy(obs), target)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
    first, last = np.mean(losses[:10]), np.mean(losses[-10:])
    assert last < 0.3 * first, (first, last)
