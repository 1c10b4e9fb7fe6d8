"""A training smoke test: a small MLP policy trained on CPU for a few hundred steps on `RecordingDataset` windows of a
real recording (the scripted pick policy of SimreelLiftCube-v1, its observations recorded) learns the policy: the
training loss falls, and on the held-out episodes it predicts the actions far better than their mean does."""

from __future__ import annotations

import torch

from simreel.training import EpisodeChoice, RecordingDataset, compute_stats

FEATURES = ["obs", "actions"]
HORIZON = 2  # an action chunk: the step's action and the next


def _batches(ds: RecordingDataset, stats, **loader) -> tuple[torch.Tensor, torch.Tensor]:
    """Every sample of `ds` as (normalized observation, action chunk) tensors, read through a DataLoader."""
    obs, actions = [], []
    for batch in torch.utils.data.DataLoader(ds, batch_size=32, **loader):
        obs.append(stats.normalize("obs/state", batch["obs/state"][:, -1].double()).float())
        actions.append(batch["actions"].flatten(1))
    return torch.cat(obs), torch.cat(actions)


def test_a_small_policy_learns_the_recorded_actions(record):
    rec = record("SimreelLiftCube-v1", 5, 30, "--record-obs")
    def sets(split):
        return RecordingDataset(rec, features=FEATURES, horizon=HORIZON,
                                episodes=EpisodeChoice(split=split, val_fraction=0.2, seed=1))

    with sets("train") as train, sets("val") as val:
        assert len(train.episodes) == 4 and len(val.episodes) == 1
        stats = compute_stats(train)
        x, y = _batches(train, stats, shuffle=False)
        x_val, y_val = _batches(val, stats)
    assert y.shape == (len(x), HORIZON * 4)  # pd_ee_delta_pos: 3 deltas and the gripper, two steps

    torch.manual_seed(0)
    policy = torch.nn.Sequential(torch.nn.Linear(x.shape[1], 128), torch.nn.ReLU(), torch.nn.Linear(128, 128),
                                 torch.nn.ReLU(), torch.nn.Linear(128, y.shape[1]))
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3)
    losses = []
    for _ in range(300):
        rows = torch.randint(len(x), (64,))
        loss = torch.nn.functional.mse_loss(policy(x[rows]), y[rows])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())

    first, last = sum(losses[:20]) / 20, sum(losses[-20:]) / 20
    assert last < 0.2 * first, (first, last)
    with torch.no_grad():
        held_out = torch.nn.functional.mse_loss(policy(x_val), y_val).item()
    mean_guess = torch.nn.functional.mse_loss(y.mean(dim=0).expand_as(y_val), y_val).item()
    assert held_out < 0.5 * mean_guess, (held_out, mean_guess)
