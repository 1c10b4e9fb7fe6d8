"""Replaying an episode after its scene history (`simreel.verdicts.scene_history`; what reports say of it: `replay/run/history.py`):
real actions replays that give the recorded numbers bit for bit only after it, of recordings and of files copied by
filter and merge. The recording: SimreelLiftCube-v1's scripted grasp and lift from seed 3, three episodes; its
episode 2 replayed on a fresh env leaves the recording at step 9 (cube angular velocity off by 3 rad/s), replayed
after episodes 0 and 1 it is exact."""

from __future__ import annotations

import dataclasses
import json
import shutil

import pytest
from support.damage import corrupt_chunk
from support.mcap_samples import write

from simreel.cli.main import main
from simreel.formats import open_reader
from simreel.model.components import Tolerances
from simreel.replay.run.job import ReplayJob
from simreel.replay.run.workers import ReplayWorker
from simreel.replay.run.worklist import WorkItem, build_worklist, env_key


@pytest.fixture(scope="module")
def lift(record):
    """SimreelLiftCube-v1, scripted, seeds 3 to 5: episode 2 is exact only after its predecessors."""
    return record("SimreelLiftCube-v1", 3, 60)


def _replay(*args) -> int:
    return main(["replay", *map(str, args), "-q"])


def test_an_episode_replayed_alone_is_replayed_after_its_history(lift, tmp_path, capsys):
    report = tmp_path / "report.json"
    assert _replay(lift, "--episodes", "2", "--report", report) == 0  # was: diverged at step 9
    assert "1 exact" in capsys.readouterr().out
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    try:
        with open_reader(lift) as reader:
            key = env_key(reader.meta)
        result = worker.run(WorkItem(key, str(lift), 2))  # only episode 1's last step, then exact
        assert result.report.verdict == "exact" and result.history == []
        assert (result.report.history.episodes, result.report.history.steps) == (1, 1)
        assert worker.run(WorkItem(key, str(lift), 0)).history == []  # the scene is rebuilt: it ran 0, 1, 2
        result = worker.run(WorkItem(key, str(lift), 2))  # it ran episode 0 already: episode 1 whole
        assert result.history == [1] and result.report.verdict == "exact"
        assert "episode 2 replayed after its recorded predecessor(s) 0–1 (PhysX results depend on the scene's " \
               "history); 1 replayed for that, not verified" in result.report.notes
    finally:
        worker.close()


def test_an_episode_whose_history_cannot_be_read_says_so(lift, tmp_path):
    damaged = tmp_path / "damaged.h5"
    shutil.copy(lift, damaged)
    corrupt_chunk(damaged, "traj_0/actions", 1)
    worker = ReplayWorker(ReplayJob(mode="actions", resync=None, tolerances=Tolerances.for_mode("actions")))
    try:
        with open_reader(damaged) as reader:
            result = worker.run(WorkItem(env_key(reader.meta), str(damaged), 1))
    finally:
        worker.close()
    assert result.error is None and result.history == []  # replayed on a rebuilt scene, without its history
    assert any("replayed without the episodes that ran before it in the recorder's scene: episode 0 cannot be read"
               in limit for limit in result.report.limits)


def test_episodes_asked_in_reverse_order_are_exact(lift, capsys):
    assert _replay(lift, "--episodes", "2,1,0") == 0
    assert "3 exact" in capsys.readouterr().out


def test_two_workers_on_one_chain_replay_it_in_one_process_and_say_so(lift, capsys):
    assert _replay(lift, "--workers", "2") == 0
    out = capsys.readouterr().out
    assert "3 exact" in out
    assert "note: --workers 2: 1 process replayed these 3 episodes, which form 1 scene chain " in out


def test_two_workers_replay_each_chain_in_one_process_and_no_history_twice(record, tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    names = [f"{n}.h5" for n in "abcdefgh"]
    for name in names:  # each file's episode 1 is exact only after its episode 0 (as in the test below)
        shutil.copy(record("SimreelLiftCube-v1", 2, 60, "--seed", "4"), data / name)
    report = tmp_path / "r.json"
    assert _replay(data, "--workers", "2", "--report", report) == 0
    assert "16 exact" in capsys.readouterr().out
    lines = [json.loads(line) for line in report.with_name("r.jsonl").read_text().splitlines()]
    replayed = [e for e in lines if e["type"] == "episode"]
    workers = {name: {e["worker"] for e in replayed if e["file"].endswith(name)} for name in names}
    assert all(len(w) == 1 for w in workers.values())  # each file's one chain in one process
    assert len(set.union(*workers.values())) == 2  # and both processes replayed
    assert not [n for e in replayed for n in e["notes"] if "replayed for that" in n]  # no episode replayed as history


def test_one_env_replaying_two_files_gives_each_its_own_history(record, tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    for name in ("a.h5", "b.h5"):  # seeds 4 and 5: b.h5's episode 1 left its recording after a.h5's episodes
        shutil.copy(record("SimreelLiftCube-v1", 2, 60, "--seed", "4"), data / name)
    assert _replay(data) == 0  # one env key: one env replays a.h5, then b.h5
    assert "4 exact" in capsys.readouterr().out


def test_a_filtered_episode_without_its_history_is_replayed_without_it_and_says_so(lift, tmp_path, capsys):
    out = tmp_path / "two.h5"
    assert main(["filter", str(lift), "-o", str(out), "--episodes", "2", "-q"]) == 0
    report = tmp_path / "r.json"
    assert _replay(out, "--report", report) == 1  # diverged at step 9, as episode 2 does on a fresh scene
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "diverged"
    assert _missing_history(lift.name) in episode["limits"]


def _missing_history(recording: str) -> str:
    """The limit of episode 2 of `recording` (the lift recording) replayed from a file without episodes 0 and 1."""
    return (f"replayed on a rebuilt scene without the 2 episode(s) that ran in its scene before it when it was "
            f"recorded ({recording}, from episode 0): this file, made from another by simreel filter, merge or "
            "convert, does not hold them all; PhysX results depend on the scene's history: a divergence may come "
            "from that alone")


def test_a_re_rendered_episode_without_its_history_is_replayed_without_it_and_says_so(lift, tmp_path):
    out = tmp_path / "two.h5"
    assert main(["convert", str(lift), str(out), "--obs-mode", "state", "--episodes", "2", "-q"]) == 0
    report = tmp_path / "r.json"
    assert _replay(out, "--report", report) == 1  # as the filtered one: the same trajectory, without its history
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "diverged" and _missing_history(lift.name) in episode["limits"]


def test_a_whole_re_rendered_recording_replays_its_own_history(lift, tmp_path, capsys):
    out = tmp_path / "all.h5"
    assert main(["convert", str(lift), str(out), "--obs-mode", "state", "-q"]) == 0
    assert _replay(out, "--episodes", "2") == 0  # after its predecessors, as they are in the converted file
    out = capsys.readouterr().out
    assert "episode 2 replayed after its recorded predecessor(s) 0–1" in out  # (the re-rendered observations are
    assert "1 of 1 episode(s) verified" in out and "all verified" in out  # within tolerance of the recomputed ones)


def test_a_merged_file_replays_each_recordings_episodes_after_their_own_history(lift, record, tmp_path, capsys):
    recordings = [lift, record("SimreelLiftCube-v1", 3, 60, "--seed", "4")]
    merged = tmp_path / "merged.h5"
    assert main(["merge", *map(str, recordings), "-o", str(merged), "-q"]) == 0
    chains = [item.chain for item in build_worklist([merged], chains=True).items]
    ids = []
    for path in recordings:
        with open_reader(path) as reader:
            ids.append(reader.meta.recording_id)
    assert chains[:3] == [f"{merged}{ids[0]}#0"] * 3 and chains[3:] == [f"{merged}{ids[1]}#0"] * 3
    report = tmp_path / "r.json"
    assert _replay(merged, "--episodes", "2,5", "--report", report) == 0
    first, episode = json.loads(report.read_text())["episodes"]
    assert first["verdict"] == "exact" and "only the last step of episode 1," in first["history"]["why"]
    # after b's episode 1's last step (merged 4), not a's, on a scene rebuilt after a's episode 2
    assert episode["verdict"] == "exact" and "only the last step of episode 4," in episode["history"]["why"]


def test_a_whole_chain_filtered_by_an_older_simreel_replays_its_own_history(lift, tmp_path, capsys):
    """Copies written before copies noted where they ran (no ``origin.scene``): their recorded episodes and resets
    still tell their chain, so the whole recording filtered then replays as the recording does."""
    filtered = tmp_path / "filtered.h5"
    assert main(["filter", str(lift), "-o", str(filtered), "--episodes", "0-2", "-q"]) == 0
    with open_reader(filtered) as reader:
        episodes = [reader.read_episode(m.index) for m in reader.episodes]
        meta = reader.meta
    older = tmp_path / "older.h5"
    write(older, meta, [dataclasses.replace(ep, meta=dataclasses.replace(
        ep.meta, origin=dataclasses.replace(ep.meta.origin, scene=None))) for ep in episodes])
    report = tmp_path / "r.json"
    assert _replay(older, "--episodes", "2", "--report", report) == 0  # was: diverged, on a rebuilt scene
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "exact" and "only the last step of episode 1" in episode["history"]["why"]


def _older_conversion(lift, tmp_path, episodes: str):
    """`convert --episodes EPISODES` of the lift recording as a simreel wrote it before converted episodes noted where
    they ran (``provenance["scene"]``) and before recordings noted each episode's place (``chain``)."""
    converted = tmp_path / "converted.h5"
    assert main(["convert", str(lift), str(converted), "--obs-mode", "state", "--episodes", episodes, "-q"]) == 0
    with open_reader(converted) as reader:
        episodes_read = [reader.read_episode(m.index) for m in reader.episodes]
        meta = reader.meta
    older = tmp_path / "older.h5"
    write(older, meta, [dataclasses.replace(ep, meta=dataclasses.replace(ep.meta, chain=None, provenance=dataclasses.replace(
        ep.meta.provenance, scene=None))) for ep in episodes_read])
    return older


def test_an_episode_an_older_simreel_converted_without_its_predecessors_is_not_given_another_history(lift, tmp_path):
    """Regression: of an older `convert --episodes 0,2`, episode 2 was replayed after episode 0 as its "recorded
    predecessor" (its were 0 and 1), with no limit; and `convert --episodes 2` of that file re-ran episode 0's last
    step before its reset and wrote that it ran after episode 0: a wrong scene, made authoritative."""
    older = _older_conversion(lift, tmp_path, "0,2")
    report = tmp_path / "r.json"
    _replay(older, "--episodes", "2", "--report", report)
    (episode,) = json.loads(report.read_text())["episodes"]
    unknown = ("replayed on a rebuilt scene: made from another recording (copied, converted or replayed) by a simreel "
               "that did not note which episodes ran in its scene before it when it was recorded; PhysX results "
               "depend on the scene's history: a divergence may come from that alone")
    assert unknown in episode["limits"] and not any("predecessor" in note for note in episode["notes"])
    again = tmp_path / "again.h5"
    main(["convert", str(older), str(again), "--obs-mode", "state", "--episodes", "2", "--keep", "all", "-q"])
    with open_reader(again) as reader:
        assert reader.episode_meta(2).provenance.scene is None  # unknown, not a wrong one


def test_a_whole_chain_an_older_simreel_converted_replays_its_own_history(lift, tmp_path):
    older = _older_conversion(lift, tmp_path, "0-2")
    report = tmp_path / "r.json"
    assert _replay(older, "--episodes", "2", "--report", report) == 0
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["limits"] == [] and "episode 2 replayed after its recorded predecessor(s) 0–1 (PhysX results " \
        "depend on the scene's history); 0–1 replayed for that, not verified" in episode["notes"]


def test_a_replay_written_alone_keeps_where_it_ran(lift, tmp_path):
    """`replay --episodes 2 -o` writes episode 2 replayed after its recorded history: replaying that file, which
    lacks the history, says so (it was taken as recorded there, on a fresh scene, and diverged silently)."""
    out = tmp_path / "replayed.h5"
    assert _replay(lift, "--episodes", "2", "-o", out) == 0
    report = tmp_path / "r.json"
    assert _replay(out, "--report", report) == 1
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "diverged" and _missing_history(lift.name) in episode["limits"]


def test_a_moved_recording_is_still_the_history_of_its_copies(lift, tmp_path, capsys):
    """Regression: copies named their recording by its path only: the recording moved, a merge of it with a copy of
    its episode 2 took them for two recordings, and the copy was replayed without the history it held."""
    recording, filtered, merged = tmp_path / "a.h5", tmp_path / "f.h5", tmp_path / "m.h5"
    shutil.copy(lift, recording)
    assert main(["filter", str(recording), "-o", str(filtered), "--episodes", "2", "-q"]) == 0
    recording = recording.rename(tmp_path / "moved.h5")
    assert main(["merge", str(recording), str(filtered), "-o", str(merged), "-q"]) == 0
    report = tmp_path / "r.json"
    assert _replay(merged, "--episodes", "3", "--report", report) == 0  # was: diverged, "without the 2 episode(s)"
    (episode,) = json.loads(report.read_text())["episodes"]
    assert episode["verdict"] == "exact" and episode["limits"] == []


def test_a_new_recording_at_the_same_path_is_not_the_history_of_older_copies(lift, record, tmp_path):
    """Regression: a copy of episode 2 merged with another recording made at its recording's path (--overwrite) was
    replayed after that one's episodes 0 and 1, as if they were its own history, and its report said so."""
    recording, filtered, merged = tmp_path / "a.h5", tmp_path / "f.h5", tmp_path / "m.h5"
    shutil.copy(lift, recording)
    assert main(["filter", str(recording), "-o", str(filtered), "--episodes", "2", "-q"]) == 0
    shutil.copy(record("SimreelLiftCube-v1", 3, 60, "--seed", "4"), recording)  # recorded anew at that path
    assert main(["merge", str(recording), str(filtered), "-o", str(merged), "-q"]) == 0
    report = tmp_path / "r.json"
    assert _replay(merged, "--episodes", "3", "--report", report) == 1  # without its history, as the filtered one
    (episode,) = json.loads(report.read_text())["episodes"]
    assert not any("predecessor" in note for note in episode["notes"])
    assert any("replayed on a rebuilt scene without the 2 episode(s)" in limit for limit in episode["limits"])


def test_copies_of_a_whole_file_keep_its_recording_id_and_files_made_from_it_get_their_own(lift, tmp_path):
    def recording_id(path) -> str:
        with open_reader(path) as reader:
            return reader.meta.recording_id

    made = {"copy.mcap": ["convert", str(lift), str(tmp_path / "copy.mcap"), "-q"],
            "recovered.h5": ["recover", str(lift), "-o", str(tmp_path / "recovered.h5")],
            "filtered.h5": ["filter", str(lift), "-o", str(tmp_path / "filtered.h5"), "--episodes", "0-2", "-q"],
            "merged.h5": ["merge", str(lift), "-o", str(tmp_path / "merged.h5"), "-q"],
            "rendered.h5": ["convert", str(lift), str(tmp_path / "rendered.h5"), "--obs-mode", "state", "-q"]}
    for args in made.values():
        assert main(args) == 0
    ids = {name: recording_id(tmp_path / name) for name in made}
    assert len(recording_id(lift)) == 32
    assert ids["copy.mcap"] == ids["recovered.h5"] == recording_id(lift)  # the same recording
    others = [ids[name] for name in ("filtered.h5", "merged.h5", "rendered.h5")]
    assert len({recording_id(lift), *others}) == 4


def test_an_episode_whose_predecessor_recover_lost_is_replayed_without_its_history_and_says_so(lift, tmp_path):
    """Regression: the recovered file's episode 2 was taken for the second of its chain (its file lists 0 and 2)
    and replayed after episode 0 alone, its report saying that was its history."""
    damaged, recovered = tmp_path / "damaged.h5", tmp_path / "recovered.h5"
    shutil.copy(lift, damaged)
    corrupt_chunk(damaged, "traj_1/actions", 1)
    assert main(["recover", str(damaged), "-o", str(recovered)]) == 0
    report = tmp_path / "r.json"
    assert _replay(recovered, "--episodes", "2", "--report", report) == 1  # diverged at step 9, on a fresh scene
    (episode,) = json.loads(report.read_text())["episodes"]
    assert not any("predecessor" in note for note in episode["notes"])
    assert ("replayed on a rebuilt scene without the 2 episode(s) that ran in its scene before it when it was recorded "
            "(from episode 0): this file does not hold them all (left out of a copy, or damaged and lost by recover)") \
        in episode["limits"][0]
