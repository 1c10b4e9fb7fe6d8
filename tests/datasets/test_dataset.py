"""`simreel.datasets.dataset`: merge and filter/split, lossless for every array and every format (simreel HDF5,
MCAP, ManiSkill's own files), proven by reading the outputs back; provenance and origins; ManiSkill's loaders
read the outputs; nothing half-written is left when anything fails."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.maniskill_files import record_maniskill
from support.mcap_samples import assert_same_episode, long_sample, synthetic_episode, synthetic_meta, write
from support.small_disk import small_disk

from simreel.datasets.dataset import EpisodeCriteria, filter_recording, merge
from simreel.errors import EnvMismatchError, OutputCheckError, RecordingFileError, StorageError, UsageError
from simreel.formats import open_reader, recording_files
from simreel.model.episode import Episode
from simreel.model.meta import EpisodeMeta, RecordingMeta
from simreel.model.state_tree import LeafSpec

IMAGE = "sensor_data/base_camera/rgb"


def _image_meta() -> RecordingMeta:
    """The synthetic recording (NaN, -0.0, inf, subnormals in every float field) with a camera image as well."""
    meta = synthetic_meta()
    return dataclasses.replace(meta, obs_layout={**meta.obs_layout, IMAGE: LeafSpec((64, 64, 3), "uint8")})


def _image_episode(meta: RecordingMeta, index: int, T: int, seed: int = 0, **meta_changes) -> Episode:
    ep = synthetic_episode(meta, index, T, seed)
    ep.obs[IMAGE] = np.random.default_rng(seed + index).integers(0, 256, (T + 1, 64, 64, 3), dtype=np.uint8)
    return dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, **meta_changes))


def _episodes(path: Path) -> list[Episode]:
    with open_reader(path) as r:
        return [r.read_episode(m.index) for m in r.episodes]


def assert_copied(got: list[Episode], sources: list[tuple[Path, Episode]]) -> None:
    """`got[k]` is episode k, with every array and all metadata of `sources[k]` but its index and origin. The sources
    are recordings of one scene chain each (episodes 0, 1, ... in one scene) or copies of them."""
    assert [e.meta.index for e in got] == list(range(len(sources)))
    for ep, (path, want) in zip(got, sources, strict=True):
        origin = {"file": str(path.resolve()), "index": want.meta.index}
        before = want.meta.origin.to_json() if want.meta.origin is not None else {}
        origin["scene"] = before.get("scene") or {"file": str(path.resolve()), "start": 0, "position": want.meta.index}
        if before:
            origin["origin"] = before
        assert ep.meta.origin.to_json() == origin
        assert_same_episode(dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, index=want.meta.index,
                                                                               origin=want.meta.origin)), want)


@pytest.fixture()
def synthetic(tmp_path) -> tuple[Path, Path]:
    """a.h5 (3 episodes, one of 250 steps whose images stream through the writer's scratch file) and b.mcap (2,
    one of them 0 steps long) of the same synthetic env."""
    meta = _image_meta()
    a = write(tmp_path / "a.h5", meta, [_image_episode(meta, i, T) for i, T in enumerate((4, 250, 1))])
    b = write(tmp_path / "b.mcap", meta, [_image_episode(meta, i, T, seed=9) for i, T in enumerate((5, 0))])
    return a, b


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_merge_copies_every_array_and_its_metadata_bit_exactly(synthetic, tmp_path, suffix):
    a, b = synthetic
    out = tmp_path / f"merged{suffix}"
    report = merge([a, b], out, command="simreel merge a.h5 b.mcap")
    assert (report.checked, report.outputs[0].episodes, report.outputs[0].steps) == (5, 5, 260)
    assert [(p.name, total, taken) for p, total, taken in report.inputs] == [("a.h5", 3, 3), ("b.mcap", 2, 2)]
    sources = [(a, e) for e in _episodes(a)] + [(b, e) for e in _episodes(b)]
    assert_copied(_episodes(out), sources)
    with open_reader(out) as r, open_reader(a) as first:
        meta = r.meta
        assert meta.command == "simreel merge a.h5 b.mcap" and meta.created_utc
        assert len(meta.recording_id) == 32 and meta.recording_id != first.meta.recording_id  # a file of its own
        same = dataclasses.replace(meta, created_utc="", command="", provenance={}, recording_id=first.meta.recording_id)
        assert same.to_json() == first.meta.to_json()  # the env, its layouts and everything else as the inputs
    prov = meta.provenance
    assert prov["operation"] == "merge" and [i["path"] for i in prov["inputs"]] == [str(a), str(b)]
    sidecar = a.with_suffix(".json").stat()
    assert prov["inputs"][0]["size"] == a.stat().st_size + sidecar.st_size  # the recording's files: with its sidecar
    assert prov["inputs"][0]["mtime_ns"] == max(a.stat().st_mtime_ns, sidecar.st_mtime_ns)
    assert prov["inputs"][1]["mtime_ns"] == b.stat().st_mtime_ns
    assert prov["inputs"][1]["kind"] == "simreel MCAP recording (format 1)" and prov["inputs"][1]["episodes"] == 2
    assert prov["inputs"][0]["meta_digest"] == prov["inputs"][1]["meta_digest"]  # both written with one meta


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_episodes_of_many_blocks_merge_and_filter_bit_exactly(tmp_path, suffix):
    """An episode of three blocks of rows (the unit both copy and check at a time) comes through whole."""
    a, long = long_sample(tmp_path / "a.h5")
    meta = synthetic_meta()
    b = write(tmp_path / "b.mcap", meta, [synthetic_episode(meta, 0, 7, seed=4)])
    merged = tmp_path / f"merged{suffix}"
    report = merge([a, b], merged)
    assert (report.checked, report.outputs[0].steps) == (4, 9015)
    sources = [(a, e) for e in long] + [(b, e) for e in _episodes(b)]
    assert_copied(_episodes(merged), sources)
    filter_recording(merged, tmp_path / f"long{suffix}", EpisodeCriteria(min_steps=100))
    [got] = _episodes(tmp_path / f"long{suffix}")
    ran = {"file": str(a.resolve()), "start": 0, "position": 1}  # where it ran: episode 1 of a.h5's one chain
    assert got.meta.origin.to_json() == {"file": str(merged.resolve()), "index": 1, "scene": ran,
                                         "origin": {"file": str(a.resolve()), "index": 1, "scene": ran}}
    assert_same_episode(dataclasses.replace(got, meta=long[1].meta), long[1])


def test_the_episode_digest_covers_every_byte_however_the_rows_are_split(tmp_path):
    """`HashedRows` hashes an episode as a writer reads it, a block at a time: blocks of any size give one
    digest; one ulp of one reward, or other metadata, give another; rows read out of order are our bug."""
    from simreel.datasets.digests import HashedRows, episode_digest

    a, long = long_sample(tmp_path / "a.h5")
    changed = dataclasses.replace(long[1], rewards=long[1].rewards.copy())
    changed.rewards[8500] = np.nextafter(changed.rewards[8500], np.float32(np.inf))
    b = write(tmp_path / "b.h5", synthetic_meta(), [changed])
    with open_reader(a) as r, open_reader(b) as other:
        digests = set()
        for rows in (1000, 4096, 9000):
            hashed = HashedRows(r.open_episode(1))
            hashed.reset()
            for _ in hashed.blocks(rows):
                pass
            digests.add(hashed.digest())
        assert digests == {episode_digest(r.open_episode(1))}
        assert episode_digest(other.open_episode(1)) not in digests
        renumbered = dataclasses.replace(r.episode_meta(1), index=7)
        assert episode_digest(HashedRows(r.open_episode(1), renumbered)) not in digests
        skipping = HashedRows(r.open_episode(1))
        skipping.reset()
        with pytest.raises(RuntimeError, match="steps 10.. read before step 0 was hashed"):
            skipping.steps(10, 20)


def test_filter_and_its_rest_split_the_input_and_keep_each_origin(synthetic, tmp_path):
    a, _ = synthetic
    merged = tmp_path / "merged.h5"
    merge([a, synthetic[1]], merged)
    kept, rest = tmp_path / "kept.mcap", tmp_path / "rest.h5"
    report = filter_recording(merged, kept, EpisodeCriteria(min_steps=2, max_steps=100), rest=rest)
    assert [(o.path, o.episodes, o.steps) for o in report.outputs] == [(kept, 2, 9), (rest, 3, 251)]
    assert report.checked == 5 and report.criteria == ">= 2 steps; <= 100 steps"
    source = _episodes(merged)
    assert_copied(_episodes(kept), [(merged, source[k]) for k in (0, 3)])
    assert_copied(_episodes(rest), [(merged, source[k]) for k in (1, 2, 4)])
    # the chain of origins: kept episode 1 was episode 3 of merged.h5, which was episode 0 of b.mcap
    assert _episodes(kept)[1].meta.origin.origin.to_json() == {
        "file": str(synthetic[1]), "index": 0, "scene": {"file": str(synthetic[1]), "start": 0, "position": 0}}
    with open_reader(kept) as k, open_reader(rest) as r:
        assert k.meta.provenance["criteria"] == {"min_steps": 2, "max_steps": 100}
        assert (k.meta.provenance["part"], r.meta.provenance["part"]) == ("kept", "rest")
        assert k.meta.provenance["inputs"][0]["provenance"]["operation"] == "merge"  # the input's own, nested


@pytest.mark.parametrize(
    ("criteria", "kept"),
    [
        (EpisodeCriteria(episodes=(0, 2, 3)), [0, 2, 3]),
        (EpisodeCriteria(success=True), [1]),
        (EpisodeCriteria(success=False), [0, 2]),
        (EpisodeCriteria(episodes=(0, 1, 3), success=False), [0]),
        (EpisodeCriteria(max_steps=1), [3]),
        (EpisodeCriteria(verdicts={0: "exact", 1: "diverged", 2: "within_tolerance"},
                         keep_verdicts=("exact", "within_tolerance")), [0, 2]),
    ],
    ids=["episodes", "success", "no-success", "episodes-and-no-success", "max-steps", "verdicts"],
)
def test_criteria_combine_with_and_and_episodes_without_success_meet_neither(tmp_path, criteria, kept):
    meta = _image_meta()
    successes = [False, True, False, None]  # episode 3: its file holds no final success
    src = write(tmp_path / "src.h5", meta, [_image_episode(meta, i, T, success=s)
                                            for i, (T, s) in enumerate(zip((3, 4, 5, 1), successes, strict=True))])
    out, rest = tmp_path / "out.h5", tmp_path / "rest.mcap"
    report = filter_recording(src, out, criteria, rest=rest)
    assert [e.meta.origin.index for e in _episodes(out)] == kept
    assert [e.meta.origin.index for e in _episodes(rest)] == [i for i in range(4) if i not in kept]
    assert report.no_success == (1 if criteria.success is not None else 0)
    assert report.uncovered == (1 if criteria.verdicts is not None else 0)  # episode 3 is not in the verdicts


def test_a_real_recording_split_and_merged_back_keeps_contacts_poses_and_observations(record, tmp_path):
    src = record("PickCube-v1", 3, 12, "--poses", "--record-obs")
    first, rest = tmp_path / "first.mcap", tmp_path / "rest.h5"
    filter_recording(src, first, EpisodeCriteria(episodes=(0,)), rest=rest)
    merge([first, rest], tmp_path / "again.h5")
    got, want = _episodes(tmp_path / "again.h5"), _episodes(src)
    with open_reader(src) as reader:
        recording = {"file": str(src), "recording": reader.meta.recording_id}
    for k, ep in enumerate(got):
        assert ep.meta.origin.origin.to_json() == {"file": str(src), "index": k,  # via first.mcap or rest.h5
                                                   "scene": {**recording, "start": 0, "position": k}}
        assert_same_episode(dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, origin=None)), want[k])
    assert got[2].contact_forces.shape[1] > 0 and got[2].body_poses.shape[1] > 0 and got[2].obs["state"].size
    assert [e.meta.seed for e in got] == [3, 4, 5]


def test_inputs_of_different_envs_are_refused_before_anything_is_written(record, tmp_path):
    pick, push = record("PickCube-v1", 2, 20), record("PushCube-v1", 1, 5)
    with pytest.raises(EnvMismatchError, match=r"records another env than .*PickCube-v1.h5: env_id is 'PushCube-v1' "
                                               r"there, 'PickCube-v1' in"):
        merge([pick, push], tmp_path / "out.h5")
    assert list(tmp_path.iterdir()) == []


def test_recordings_of_other_simulator_builds_are_refused_but_simreels_own_version_may_differ(synthetic, tmp_path):
    """A merged file carries one `versions`: inputs of different ManiSkill builds are refused; simreel's own
    version does not change the physics, so the output lists each (the inputs' are in the provenance)."""
    a, b = synthetic
    meta = dataclasses.replace(_image_meta(), versions={"simreel": "0.1.0", "mani_skill": "3.0.1"})
    c = write(tmp_path / "c.h5", meta, [_image_episode(meta, 0, 2)])
    d = write(tmp_path / "d.h5", dataclasses.replace(meta, versions={"simreel": "0.2.0", "mani_skill": "3.0.1"}),
              [_image_episode(meta, 0, 3)])
    e = write(tmp_path / "e.h5", dataclasses.replace(meta, versions={"simreel": "0.1.0", "mani_skill": "3.0.2"}),
              [_image_episode(meta, 0, 3)])
    merge([c, d], tmp_path / "cd.h5")
    with open_reader(tmp_path / "cd.h5") as r:
        assert r.meta.versions == {"simreel": "0.1.0, 0.2.0", "mani_skill": "3.0.1"}
        assert [i["versions"]["simreel"] for i in r.meta.provenance["inputs"]] == ["0.1.0", "0.2.0"]
    with pytest.raises(EnvMismatchError, match="versions.mani_skill is '3.0.2' there, '3.0.1' in"):
        merge([c, e], tmp_path / "ce.h5")


# ------------------------------------------------------------------------------------------ ManiSkill's files
@pytest.fixture(scope="module")
def ms_files(tmp_path_factory) -> tuple[Path, Path]:
    """Two RecordEpisode files of PickCube-v1 (state observations, env states, rewards; seeds 0 and 1 each)."""
    folder = tmp_path_factory.mktemp("maniskill")
    first = record_maniskill(folder, "PickCube-v1", name="run1", episodes=2, steps=12, obs_mode="state",
                             source_type="teleop")
    second = record_maniskill(folder, "PickCube-v1", name="run2", episodes=2, steps=7, obs_mode="state",
                              source_type="teleop")
    return first, second


def _loader_arrays(path: Path) -> dict[str, np.ndarray]:
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset, load_h5_data

    data = ManiSkillTrajectoryDataset(str(path))
    out = {"actions": data.actions, "obs": data.obs, "rewards": data.rewards, "success": data.success}
    data.data.close()
    with h5py.File(path, "r") as f:
        out["traj_last"] = load_h5_data(f[f"traj_{len(data.episodes) - 1}"])["env_states"]["actors"]["cube"]
    return out


def test_maniskill_files_merge_mixed_with_simreel_files_and_maniskills_loaders_read_the_result(ms_files, tmp_path):
    first, second = ms_files
    mixed = tmp_path / "run2.mcap"
    merge([second], mixed)  # ManiSkill's file as a simreel MCAP: the same env, another format
    out = tmp_path / "all.h5"
    merge([first, mixed], out)
    sources = [(first, e) for e in _episodes(first)] + [(mixed, e) for e in _episodes(mixed)]
    assert_copied(_episodes(out), sources)
    with open_reader(out) as r:
        assert r.meta.source == {"format": "maniskill", "source_type": "teleop"}  # what both inputs' sources share
        assert r.meta.provenance["inputs"][0]["source"]["sidecar"] == str(first.with_suffix(".json"))
    doc = json.loads(out.with_suffix(".json").read_text())
    assert [e["episode_id"] for e in doc["episodes"]] == [0, 1, 2, 3]
    assert [e["elapsed_steps"] for e in doc["episodes"]] == [12, 12, 7, 7]
    loaded = _loader_arrays(out)
    np.testing.assert_array_equal(loaded["actions"], np.concatenate([e.actions for _, e in sources]))
    np.testing.assert_array_equal(loaded["obs"], np.concatenate([e.obs["state"][:-1] for _, e in sources]))
    np.testing.assert_array_equal(loaded["rewards"], np.concatenate([e.rewards for _, e in sources]))
    np.testing.assert_array_equal(loaded["traj_last"], sources[-1][1].env_states["actors/cube"])


def test_a_filtered_maniskill_file_is_read_by_maniskills_loaders(ms_files, tmp_path):
    first, _ = ms_files
    out, rest = tmp_path / "one.h5", tmp_path / "rest.h5"
    filter_recording(first, out, EpisodeCriteria(episodes=(1,)), rest=rest)
    want = _episodes(first)
    for path, episodes in ((out, [want[1]]), (rest, [want[0]])):
        assert_copied(_episodes(path), [(first, e) for e in episodes])
        doc = json.loads(path.with_suffix(".json").read_text())
        assert [e["episode_id"] for e in doc["episodes"]] == [0] and doc["episodes"][0]["episode_seed"] == \
            episodes[0].meta.seed
        np.testing.assert_array_equal(_loader_arrays(path)["actions"], episodes[0].actions)


def test_episodes_are_selected_by_the_steps_they_hold_not_by_the_sidecars_word(ms_files, tmp_path):
    """A sidecar that understates `elapsed_steps`, or gives none, does not drop the episode from a selection by
    length (nor keep one it overstates): filter goes by the actions each episode holds (7 here)."""
    src = tmp_path / "stale.h5"
    src.write_bytes(ms_files[1].read_bytes())
    doc = json.loads(ms_files[1].with_suffix(".json").read_text())
    doc["episodes"][0]["elapsed_steps"] = 3
    del doc["episodes"][1]["elapsed_steps"]
    src.with_suffix(".json").write_text(json.dumps(doc))
    report = filter_recording(src, tmp_path / "long.h5", EpisodeCriteria(min_steps=5))
    assert report.outputs[0].episodes == 2 and report.outputs[0].steps == 14
    assert [e.length for e in _episodes(tmp_path / "long.h5")] == [7, 7]
    doc["episodes"][0]["elapsed_steps"] = 50
    src.with_suffix(".json").write_text(json.dumps(doc))
    with pytest.raises(UsageError, match="nothing matches"):
        filter_recording(src, tmp_path / "longer.h5", EpisodeCriteria(min_steps=40))
    assert not (tmp_path / "longer.h5").exists()


# ------------------------------------------------------------------------------------------ nothing half-written
def _leftovers(folder: Path, *names: str) -> list[str]:
    """The outputs' files, and the staging files they were written under, that exist in `folder`."""
    staged = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    return sorted(staged + [p.name for name in names for p in recording_files(folder / name) if p.exists()])


def test_an_interruption_removes_every_output_and_leaves_the_inputs(synthetic, tmp_path, monkeypatch):
    from simreel.formats.hdf5.reader import Hdf5Reader

    a, _ = synthetic
    before = a.read_bytes()
    real = Hdf5Reader.open_episode

    def interrupted(self, index):
        if index == 2:
            raise KeyboardInterrupt
        return real(self, index)

    monkeypatch.setattr(Hdf5Reader, "open_episode", interrupted)
    with pytest.raises(KeyboardInterrupt):
        filter_recording(a, tmp_path / "out.h5", EpisodeCriteria(episodes=(0,)), rest=tmp_path / "rest.mcap")
    assert _leftovers(tmp_path, "out.h5", "rest.mcap") == []
    assert a.read_bytes() == before


def test_an_output_that_does_not_read_back_as_its_source_is_our_bug_and_is_removed(synthetic, tmp_path, monkeypatch):
    """The check after writing is real: a writer that changed one value of one array is caught, named, and its
    output removed."""
    from simreel.formats.base import EpisodeWriter
    from simreel.model.blocks import StepBlock

    real = EpisodeWriter.write_rows

    def off_by_one_ulp(self, rows):
        read_blocks = rows.blocks

        def altered(n=None):
            for start, block in read_blocks(n):
                if rows.meta.index == 1 and start <= 3 < start + block.rows:
                    rewards = block["rewards"].copy()
                    rewards[3 - start] = np.nextafter(rewards[3 - start], np.float32(np.inf))
                    block = StepBlock.of({**block.arrays, "rewards": rewards})
                yield start, block

        rows.blocks = altered
        real(self, rows)

    monkeypatch.setattr(EpisodeWriter, "write_rows", off_by_one_ulp)
    a, b = synthetic
    with pytest.raises(OutputCheckError, match=r"merged.mcap: episode 1 does not read back as episode 1 of "
                                               r".*a.h5: rewards is float32 \(250,\) here, float32 \(250,\) there"):
        merge([a, b], tmp_path / "merged.mcap")
    assert _leftovers(tmp_path, "merged.mcap") == []


def test_an_input_that_changes_during_the_copy_is_refused(synthetic, tmp_path, monkeypatch):
    import simreel.datasets.dataset as dataset

    a, b = synthetic
    real = dataset._plan

    def touch_after_planning(*args):
        items = real(*args)
        os.utime(b, ns=(b.stat().st_atime_ns, b.stat().st_mtime_ns + 1))  # another process writes to it
        return items

    monkeypatch.setattr(dataset, "_plan", touch_after_planning)
    with pytest.raises(RecordingFileError, match="b.mcap: changed while it was being copied"):
        merge([a, b], tmp_path / "out.h5")
    assert _leftovers(tmp_path, "out.h5") == []


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda a, b, t: merge([a, a], t / "o.h5"), UsageError, "a.h5 is given twice"),
        (lambda a, b, t: merge([a, b], a), UsageError, r"-o .*a.h5 is input .*a.h5; write it to another file"),
        (lambda a, b, t: merge([a, b], t / "a.hdf5"), UsageError, r"-o .*a.json is a file of input .*a.h5"),
        (lambda a, b, t: merge([a, b], t / "b.mcap", overwrite=True), UsageError, r"-o .*b.mcap is input"),
        (lambda a, b, t: merge([a, t / "none.h5"], t / "o.h5"), RecordingFileError, "none.h5: no such file"),
        (lambda a, b, t: filter_recording(a, t / "o.h5", EpisodeCriteria(episodes=(7,))), RecordingFileError,
         r"a.h5: no episode 7 \(episodes: 0, 1, 2\)"),
        (lambda a, b, t: filter_recording(a, t / "o.h5", EpisodeCriteria(min_steps=1000)), UsageError,
         "no episode to write to .*o.h5: nothing matches \\(of 3 episode\\(s\\): 0 meet >= 1000 steps\\); nothing written"),
        (lambda a, b, t: filter_recording(a, t / "o.h5", EpisodeCriteria()), UsageError, "no criterion"),
        (lambda a, b, t: filter_recording(a, t / "o.h5", EpisodeCriteria(min_steps=1), rest=t / "o.h5"),
         UsageError, r"--rest .*o.h5 is also written by -o"),
        (lambda a, b, t: filter_recording(a, t / "o.txt", EpisodeCriteria(min_steps=1)), UsageError,
         "unknown recording suffix '.txt'"),
        (lambda a, b, t: EpisodeCriteria(min_steps=5, max_steps=2), UsageError, "--min-steps 5 is above --max-steps 2"),
        (lambda a, b, t: EpisodeCriteria(max_steps=-1), UsageError, "--max-steps must be >= 0, got -1"),
    ],
    ids=["twice", "out-is-input", "out-sidecar-is-inputs", "overwrite-an-input", "missing-input", "no-episode",
         "empty-selection", "no-criterion", "rest-is-out", "suffix", "min-above-max", "negative"],
)
def test_bad_input_is_refused_and_nothing_is_written(synthetic, tmp_path, call, error, message):
    a, b = synthetic
    before = sorted(tmp_path.iterdir())
    with pytest.raises(error, match=message):
        call(a, b, tmp_path)
    assert sorted(tmp_path.iterdir()) == before and a.read_bytes() == a.read_bytes()


def test_an_empty_rest_is_a_recording_of_no_episode(synthetic, tmp_path):
    a, _ = synthetic
    report = filter_recording(a, tmp_path / "all.h5", EpisodeCriteria(max_steps=1000), rest=tmp_path / "none.mcap")
    assert [o.episodes for o in report.outputs] == [3, 0]
    with open_reader(tmp_path / "none.mcap") as r:
        assert r.episodes == [] and r.meta.provenance["part"] == "rest"


def test_files_written_before_provenance_existed_still_read(synthetic, tmp_path):
    """A recording whose metadata has no `provenance` and whose episodes have no `origin` (written before they
    existed) reads with both empty."""
    from simreel.formats.hdf5.layout import EPISODE_ATTR, META_ATTR

    old = tmp_path / "old.h5"
    old.write_bytes(synthetic[0].read_bytes())
    with h5py.File(old, "a") as f:
        meta = json.loads(f.attrs[META_ATTR])
        del meta["provenance"]
        f.attrs[META_ATTR] = json.dumps(meta)
        for name in f:
            episode = json.loads(f[name].attrs[EPISODE_ATTR])
            del episode["origin"]
            f[name].attrs[EPISODE_ATTR] = json.dumps(episode)
    with open_reader(old) as r:
        assert r.meta.provenance == {} and all(m.origin is None for m in r.episodes)
        assert isinstance(r.episodes[0], EpisodeMeta)


@pytest.mark.slow
def test_maniskills_replay_trajectory_replays_a_merged_file_bit_exactly(record, maniskill_env, tmp_path):
    """The merged sidecar gives each traj_N the seed of the episode it holds: ManiSkill's own replay, which resets
    from the sidecar, reproduces every state of every renumbered episode."""
    from support.maniskill_files import replay_maniskill

    first, second = record("PickCube-v1", 2, 20), record("PickCube-v1", 1, 20, "--seed", "30")  # one time limit: one env
    merged = tmp_path / "merged.h5"
    merge([second, first], merged)
    replayed = replay_maniskill(merged, maniskill_env)
    with h5py.File(replayed, "r") as f:
        for k, ep in enumerate(_episodes(merged)):
            assert ep.meta.seed == [30, 3, 4][k]
            for key in ("actors/cube", "articulations/panda"):
                np.testing.assert_array_equal(f[f"traj_{k}/env_states/{key}"][()], ep.env_states[key])


def test_report_verdicts_find_the_file_by_its_real_path_and_only_its_episodes(synthetic, tmp_path, monkeypatch):
    from simreel.datasets.dataset import report_verdicts
    from simreel.datasets.inputs import file_identity

    a, b = synthetic
    link = tmp_path / "link.h5"
    link.symlink_to(a)
    files = {str(a): file_identity(a), str(b): (1, 2)}
    verdicts = {(str(a), 0): "exact", (str(a), 2): "diverged", (str(b), 0): "exact"}
    monkeypatch.chdir(tmp_path)
    assert report_verdicts("a.h5", verdicts, files, "r.json") == {0: "exact", 2: "diverged"}  # relative, as typed
    assert report_verdicts(link, verdicts, files, "r.json") == {0: "exact", 2: "diverged"}  # the file it names
    with pytest.raises(UsageError, match="b.mcap changed since r.json verified it"):
        report_verdicts(b, verdicts, files, "r.json")
    with pytest.raises(RecordingFileError, match="gone.h5: no such file"):
        report_verdicts("gone.h5", verdicts, files, "r.json")


def test_an_input_with_a_damaged_episode_is_refused_naming_it(tmp_path):
    """Issue 17: an episode the reader cannot read must never vanish silently, from a merge either."""
    meta = synthetic_meta(poses=False)
    a = write(tmp_path / "a.h5", meta, [synthetic_episode(meta, i, 4) for i in range(2)])
    with h5py.File(a, "r+") as f:
        del f["traj_1"].attrs["simreel_episode"]  # a half-written or damaged group
    with pytest.raises(RecordingFileError) as err:
        merge([a], tmp_path / "out.h5", command="simreel merge a.h5")
    assert str(err.value).startswith(f"{a}: 1 damaged episode(s) (traj_1: no simreel_episode attribute")
    assert f"`simreel recover {a} -o OUT` copies the intact ones" in str(err.value)
    assert not (tmp_path / "out.h5").exists()


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
def test_a_merge_the_disk_cannot_hold_names_its_output_and_leaves_nothing(tmp_path, suffix):
    """The writer of the staged output says what it committed "stays readable" under its staging name, which the
    merge then removes: the error names OUT and says nothing was written."""
    long, _ = long_sample(tmp_path / "long.h5")
    with small_disk(tmp_path, 256) as disk:
        out = disk / f"m{suffix}"
        with pytest.raises(StorageError) as raised:
            merge([long], out)
        assert str(raised.value) == (f"{out}: the disk is full; nothing was written and the inputs are unchanged; free "
                                     "some space or write to another disk")
        assert [p for p in disk.iterdir() if p.name != "lost+found"] == []


def test_an_output_whose_staged_recording_another_command_removed_is_not_published(tmp_path):
    """Regression (a race a review reproduced): a merge removing another's staged output while that one checked it
    (holding no writer lock then) made the other publish nothing, or with --overwrite delete the old OUT, and exit 0."""
    from simreel.datasets.staged import StagedOutput, Target

    meta = synthetic_meta()
    old = write(tmp_path / "out.h5", meta, [synthetic_episode(meta, 0, 3)])
    staged = StagedOutput.of(Target(old, meta, overwrite=True))
    write(staged.staged.path, meta, [synthetic_episode(meta, 0, 4)])
    staged.staged.path.unlink()  # what the other command removed
    with pytest.raises(UsageError, match="was removed by another command while this one ran; nothing was written"):
        staged.check_free()
    assert old.is_file()
