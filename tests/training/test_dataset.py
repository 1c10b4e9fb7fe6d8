"""`RecordingDataset` on real recordings of three tasks (HDF5 and MCAP): every sample equals the source rows bit for
bit, pad masks sit where the windows leave the episode, actions are padded by the control mode, DataLoader workers
read through their own handles, a replay report's verdicts choose the episodes, the split is by episode, and a
feature a file lacks is named with the file and the episode."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from simreel.errors import RecordingFileError, UsageError
from simreel.formats import open_reader, open_writer
from simreel.training import EpisodeChoice, RecordingDataset

FEATURES = {
    "pick": ["obs", "env_states/actors/cube", "actions", "rewards", "success"],
    "push": ["obs/state", "env_states", "actions", "contact_forces", "terminated"],
    "stack": ["env_states/articulations/panda_wristcam", "actions", "rewards", "info"],
}


def _source_arrays(path: Path) -> list[dict[str, np.ndarray]]:
    """Every episode of `path` as its reader gives it whole: field name -> all its rows."""
    with open_reader(path) as reader:
        return [reader.read_episode(m.index).fields() for m in reader.episodes]


@pytest.mark.parametrize("task", sorted(FEATURES))
def test_every_sample_equals_the_source_rows_bit_for_bit(three_tasks, task):
    history, horizon = 3, 4
    source = _source_arrays(three_tasks[task])
    with RecordingDataset(three_tasks[task], features=FEATURES[task], history=history, horizon=horizon,
                          action_pad="edge") as ds:
        assert len(ds) == sum(len(e["actions"]) for e in source)
        for k in range(len(ds)):
            sample = ds[k]
            episode, t = sample["episode"], sample["step"]
            arrays = source[episode]
            length = len(arrays["actions"])
            for field in ds.fields:
                rows = arrays[field.name]
                if field.per_state:  # rows t-2..t, before the reset: row 0
                    want_rows = [max(0, r) for r in range(t - history + 1, t + 1)]
                    want_pad = [r < 0 for r in range(t - history + 1, t + 1)]
                else:  # rows t..t+3, past the end: the last
                    want_rows = [min(length - 1, r) for r in range(t, t + horizon)]
                    want_pad = [r >= length for r in range(t, t + horizon)]
                got = sample[field.name]
                assert got.dtype == rows.dtype and got.tobytes() == rows[want_rows].tobytes(), (field.name, k)
                assert sample[f"{field.name}_is_pad"].tolist() == want_pad


def test_actions_past_the_end_are_padded_by_the_control_mode(three_tasks):
    # delta modes: zero arm deltas, the gripper command held (ManiSkill's diffusion-policy baseline)
    for task in ("pick", "push"):
        with RecordingDataset(three_tasks[task], features=["actions"], horizon=6) as ds:
            last = ds.episodes[0].length - 1
            chunk, is_pad = ds[last]["actions"], ds[last]["actions_is_pad"]
            real = _source_arrays(three_tasks[task])[0]["actions"][last]
            assert is_pad.tolist() == [False] + [True] * 5
            assert chunk[0].tobytes() == real.tobytes()
            assert (chunk[1:, :-1] == 0).all() and (chunk[1:, -1] == real[-1]).all()
    # an absolute mode (pd_joint_pos): the last target again
    with RecordingDataset(three_tasks["stack"], features=["actions"], horizon=6) as ds:
        last = ds.episodes[0].length - 1
        chunk = ds[last]["actions"]
        assert (chunk[1:] == chunk[0]).all() and ds[last]["actions_is_pad"].sum() == 5


def test_dataloader_workers_open_their_own_handles_and_give_the_same_samples(three_tasks):
    with RecordingDataset(three_tasks["push"], features=["obs/state", "actions"], history=2, horizon=3) as ds:
        loader = torch.utils.data.DataLoader(ds, batch_size=16, num_workers=2, shuffle=False)
        batches = list(loader)
        assert not ds.cache._readers  # the workers read; the main process opened nothing
        got = torch.cat([b["actions"] for b in batches]).numpy()
        want = np.stack([ds[k]["actions"] for k in range(len(ds))])
        assert got.tobytes() == want.tobytes()
        assert torch.cat([b["step"] for b in batches]).tolist() == [ds[k]["step"] for k in range(len(ds))]


def test_the_block_cache_stays_within_its_bytes(three_tasks):
    with RecordingDataset(three_tasks["pick"], features=["obs", "actions"], cache_bytes=1) as ds:
        ds.cache.rows = 4  # small blocks: many of them
        for k in range(len(ds)):
            ds[k]
        assert len(ds.cache._blocks) == 1  # the budget keeps one block, the one read last


def test_a_feature_the_file_lacks_names_the_file_and_the_episode(three_tasks):
    stack = three_tasks["stack"]
    with pytest.raises(RecordingFileError, match=re.escape(f"{stack}: episode 0 has no obs (it was recorded without "
                                                           "observations: record with --record-obs")):
        RecordingDataset(stack, features=["obs", "actions"])
    with pytest.raises(RecordingFileError, match=re.escape(f"{stack}: episode 0 has no env_states/actors/nothing "
                                                           "(its env_states fields are env_states/actors/")):
        RecordingDataset(stack, features=["env_states/actors/nothing"])


@pytest.fixture(scope="module")
def pick_copy(three_tasks, tmp_path_factory) -> Path:
    """The PickCube recording copied to MCAP: a second file of the same task."""
    out = tmp_path_factory.mktemp("copy") / "pick.mcap"
    with open_reader(three_tasks["pick"]) as r, open_writer(out, r.meta) as w:
        for m in r.episodes:
            w.write_rows(r.open_episode(m.index))
    return out


def test_files_of_one_set_need_the_same_features(three_tasks, pick_copy):
    with pytest.raises(UsageError, match=r"push.mcap: obs/state is float32 \(\d+,\), but .*pick.h5 has float32"):
        RecordingDataset([three_tasks["pick"], three_tasks["push"]], features=["obs/state", "actions"])
    both = RecordingDataset([three_tasks["pick"], pick_copy], features=["obs/state", "actions"])
    assert len(both) == 2 * 90 and [(Path(e.path), e.index) for e in both.episodes] == [
        (three_tasks["pick"], 0), (three_tasks["pick"], 1), (three_tasks["pick"], 2), (pick_copy, 0), (pick_copy, 1),
        (pick_copy, 2)]
    assert both[90 + 7]["actions"].tobytes() == both[7]["actions"].tobytes()


def test_the_split_is_by_episode_and_seeded(three_tasks, pick_copy):
    files = [three_tasks["pick"], pick_copy]
    sides = {split: RecordingDataset(files, features=["actions"], episodes=EpisodeChoice(split=split, val_fraction=0.34, seed=7))
             for split in ("train", "val")}
    train, val = ({(e.path, e.index) for e in sides[s].episodes} for s in ("train", "val"))
    assert len(val) == 2 and len(train) == 4 and not train & val
    again = RecordingDataset(files, features=["actions"], episodes=EpisodeChoice(split="val", val_fraction=0.34, seed=7))
    assert [(e.path, e.index) for e in again.episodes] == [(e.path, e.index) for e in sides["val"].episodes]
    with pytest.raises(UsageError, match="split='test': give 'train', 'val' or None"):
        EpisodeChoice(split="test")


def test_a_report_keeps_the_verified_episodes_by_default(nudged):
    rec, report = nudged
    assert [e.index for e in RecordingDataset(rec, episodes=EpisodeChoice(report=report)).episodes] == [0, 2]
    assert [(e.index, e.verdict) for e in RecordingDataset(rec, episodes=EpisodeChoice(report=report, keep=("diverged",))).episodes] == [
        (1, "diverged")]
    assert len(RecordingDataset(rec).episodes) == 3  # no report: every episode
    with pytest.raises(UsageError, match="keep='exact': give a tuple of verdicts"):
        EpisodeChoice(report=report, keep="exact")


def test_a_report_that_does_not_cover_a_file_is_refused(nudged, three_tasks):
    _, report = nudged
    with pytest.raises(UsageError, match=re.escape(f"{report} holds no verdict for {three_tasks['stack']}")):
        RecordingDataset(three_tasks["stack"], episodes=EpisodeChoice(report=report))


def test_options_are_checked_when_given(three_tasks):
    with pytest.raises(UsageError, match="history=0: give a whole number of steps >= 1"):
        RecordingDataset(three_tasks["pick"], history=0)
    with pytest.raises(UsageError, match="action_pad='zero': give one of auto, edge, hold"):
        RecordingDataset(three_tasks["pick"], action_pad="zero")
    with pytest.raises(UsageError, match="window=3: give only the options SampleOptions has: features, history"):
        RecordingDataset(three_tasks["pick"], window=3)
