"""Which episodes ran in an episode's scene before it (`simreel.verdicts.scene_history`), on hand-made episode lists: recorded
ones (chains by sub-scene and rebuilding reset) and copies made by filter and merge (by where they say they ran)."""

from __future__ import annotations

from simreel.model.meta import EpisodeMeta
from simreel.verdicts.scene_history import SceneChains, run_scenes


def _indices(episodes: list[EpisodeMeta], index: int) -> list[int] | None:
    """Episode `index`'s history in the file of `episodes` (None: the file does not hold it all)."""
    chains = SceneChains(episodes)
    return [ep.index for ep in chains.history(index)] if chains.complete(index) else None


def _copy(index: int, recording: str, position: int, start: int = 0, recording_id: str = "") -> EpisodeMeta:
    """Episode `index` of a filtered or merged file: a copy of the episode that ran `position` episodes after episode
    `start` of `recording` (whose `RecordingMeta.recording_id` is `recording_id`), in one scene."""
    scene = {"file": recording, "start": start, "position": position}
    scene.update({"recording": recording_id} if recording_id else {})
    return EpisodeMeta(index, origin={"file": recording, "index": start + position, "scene": scene})


def test_the_history_runs_back_to_the_first_episode_of_its_sub_scene():
    episodes = [EpisodeMeta(i) for i in range(4)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], [0, 1], [0, 1, 2]]


def test_a_reset_that_rebuilt_the_scene_starts_a_new_history():
    episodes = [EpisodeMeta(0), EpisodeMeta(1), EpisodeMeta(2, reconfigured=True, seed=2), EpisodeMeta(3),
                EpisodeMeta(4)]
    assert _indices(episodes, 2) == []  # its own reset rebuilt the scene
    assert _indices(episodes, 4) == [2, 3]  # the rebuilding episode starts the chain
    assert _indices(episodes, 1) == [0]


def test_only_episodes_of_the_same_sub_scene_count():
    episodes = [EpisodeMeta(0, env_idx=0), EpisodeMeta(1, env_idx=1), EpisodeMeta(2, env_idx=0),
                EpisodeMeta(3, env_idx=1, reconfigured=True), EpisodeMeta(4, env_idx=1)]
    assert _indices(episodes, 2) == [0]
    assert _indices(episodes, 1) == []  # the first of sub-scene 1: the recorder's env was fresh
    assert _indices(episodes, 4) == [3]


def test_an_unknown_rebuild_is_taken_as_none():
    episodes = [EpisodeMeta(0, reconfigured=None), EpisodeMeta(1, reconfigured=None), EpisodeMeta(2, reconfigured=None)]
    assert _indices(episodes, 2) == [0, 1]  # one predecessor too many costs time, one too few a wrong verdict


def test_copies_of_two_recordings_have_each_their_own_history():
    episodes = [_copy(0, "/a.h5", 0), _copy(1, "/a.h5", 1), _copy(2, "/b.h5", 0), _copy(3, "/b.h5", 1)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], [], [2]]  # b's first ran on a fresh scene


def test_a_copy_whose_predecessors_were_left_out_has_no_history_here():
    episodes = [_copy(0, "/a.h5", 0), _copy(1, "/a.h5", 2), _copy(2, "/a.h5", 3)]  # a's episode 1 left out
    assert [_indices(episodes, i) for i in range(3)] == [[], None, None]


def test_copies_in_another_order_than_they_ran_still_hold_their_history():
    episodes = [_copy(0, "/a.h5", 1), _copy(1, "/a.h5", 0)]  # convert --episodes 1,0 of a control-mode conversion
    assert [_indices(episodes, i) for i in range(2)] == [[1], []]


def test_the_same_chain_copied_twice_takes_the_copies_just_before():
    episodes = [_copy(0, "/a.h5", 0), _copy(1, "/a.h5", 1), _copy(2, "/a.h5", 0), _copy(3, "/a.h5", 1)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], [], [2]]


def test_a_copy_that_does_not_say_where_it_ran_has_no_known_history():
    episodes = [EpisodeMeta(0, origin={"file": "/a.h5", "index": 3})]
    assert _indices(episodes, 0) is None and SceneChains(episodes).copied_scene(0, "/c.h5", "") is None


def test_a_copy_of_a_copy_keeps_the_recording_it_ran_in():
    copied = SceneChains([_copy(0, "/a.h5", 4, start=2)])  # a filtered file's episode
    recorded = SceneChains([EpisodeMeta(0), EpisodeMeta(1)])
    assert copied.copied_scene(0, "/f.h5", "f1").to_json() == {"file": "/a.h5", "start": 2, "position": 4}
    assert recorded.copied_scene(1, "/r.h5", "").to_json() == {"file": "/r.h5", "start": 0, "position": 1}
    assert recorded.copied_scene(1, "/r.h5", "r1").to_json() == {"file": "/r.h5", "recording": "r1", "start": 0, "position": 1}
    again = SceneChains([_copy(0, "/a.h5", 4, start=2, recording_id="a1")])
    assert again.copied_scene(0, "/f.h5", "f1").to_json() == {"file": "/a.h5", "recording": "a1", "start": 2, "position": 4}


def test_copies_are_of_one_recording_by_its_id_wherever_it_was():
    """A recording moved between copies stays one chain; another recorded at its path (--overwrite) is another."""
    moved = [_copy(0, "/a.h5", 0, recording_id="a1"), _copy(1, "/b.h5", 1, recording_id="a1")]
    assert [_indices(moved, i) for i in range(2)] == [[], [0]]
    replaced = [_copy(0, "/a.h5", 0, recording_id="a2"), _copy(1, "/a.h5", 1, recording_id="a1")]
    assert [_indices(replaced, i) for i in range(2)] == [[], None]


def test_a_converted_episode_says_where_it_ran_in_its_provenance():
    scene = {"file": "/a.h5", "start": 0, "position": 1}
    episodes = [EpisodeMeta(3, provenance={"source_episode": 3, "scene": scene})]  # convert --episodes 3 of a.h5
    assert _indices(episodes, 3) is None and SceneChains(episodes).copied_scene(3, "/c.h5", "c1").to_json() == scene


def test_a_run_of_episodes_in_one_env_is_one_chain_until_a_rebuild():
    episodes = [EpisodeMeta(5), EpisodeMeta(2), EpisodeMeta(7, reconfigured=True), EpisodeMeta(1)]
    scenes = run_scenes(episodes, "/out.h5", "o1")
    assert {i: (s.start, s.position) for i, s in scenes.items()} == {5: (5, 0), 2: (5, 1), 7: (7, 0), 1: (7, 1)}
    assert {(s.file, s.recording) for s in scenes.values()} == {("/out.h5", "o1")}


def _old_copy(index: int, recorded_index: int, **changes) -> EpisodeMeta:
    """Episode `index` of a file filtered or merged by a simreel that did not note where copies ran: a copy of
    episode `recorded_index` of /a.h5 (through a filtered file in between)."""
    inner = {"file": "/a.h5", "index": recorded_index}
    return EpisodeMeta(index, origin={"file": "/f.h5", "index": index, "origin": inner}, **changes)


def test_older_copies_of_a_whole_chain_have_their_history():
    episodes = [_old_copy(0, 0), _old_copy(1, 1), _old_copy(2, 2)]
    assert [_indices(episodes, i) for i in range(3)] == [[], [0], [0, 1]]


def test_older_copies_start_a_chain_where_the_scene_was_rebuilt_and_lose_it_at_a_gap():
    episodes = [_old_copy(0, 3, reconfigured=True), _old_copy(1, 4), _old_copy(2, 6), _old_copy(3, 1)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], None, None]  # 5 left out; 0 left out


def test_older_copies_of_parallel_envs_are_unknown():
    episodes = [_old_copy(0, 0), _old_copy(1, 1, env_idx=1)]
    assert [_indices(episodes, i) for i in range(2)] == [None, None]


def test_an_older_copy_continues_the_chain_of_a_copy_that_says_where_it_ran():
    """Episodes 0-1 of /a.h5 copied with their scene noted (merged now), episode 2 by an older filter's --rest."""
    episodes = [_copy(0, "/a.h5", 0), _copy(1, "/a.h5", 1), _old_copy(2, 2)]
    assert _indices(episodes, 2) == [0, 1]


def _recorded(index: int, start: int, position: int) -> EpisodeMeta:
    """Episode `index` as simreel's recorder notes it: `position` episodes after episode `start` in one scene."""
    return EpisodeMeta(index, chain={"start": start, "position": position})


def test_an_episode_its_file_lacks_leaves_a_gap_in_its_chain():
    """Episode 1 damaged and left out (recover): 2 is not taken for the second episode of its chain."""
    episodes = [_recorded(0, 0, 0), _recorded(2, 0, 2), _recorded(3, 0, 3)]
    assert [_indices(episodes, i) for i in (0, 2, 3)] == [[], None, None]
    assert SceneChains(episodes).copied_scene(2, "/r.h5", "r1").to_json() == {"file": "/r.h5", "recording": "r1", "start": 0,
                                                                    "position": 2}


def test_an_episode_of_no_step_the_recorder_discarded_leaves_no_gap():
    episodes = [_recorded(1, 1, 0), _recorded(2, 1, 1), _recorded(4, 4, 0)]  # 0 and 3 had no step (a reset after
    assert [_indices(episodes, i) for i in (1, 2, 4)] == [[], [1], []]  # a reset; 3's rebuilt the scene)


def _old_conversion(index: int, **changes) -> EpisodeMeta:
    """Episode `index` of a file converted (or written by replay -o, which says so in `verification` instead) by a
    simreel that noted neither where converted episodes ran nor their place: made from episode `index` of its input."""
    return EpisodeMeta(index, provenance={"source_episode": index, "verdict": "exact"}, **changes)


def test_older_conversions_of_some_episodes_are_not_a_chain_of_their_file():
    """Regression: `convert --episodes 0,2` by an older simreel: 2 was taken for the second episode of 0's chain."""
    episodes = [_old_conversion(0), _old_conversion(2), EpisodeMeta(3, verification={"verdict": "exact"})]
    assert [_indices(episodes, i) for i in (0, 2, 3)] == [[], None, None]
    assert SceneChains(episodes).copied_scene(2, "/c.h5", "c1") is None


def test_older_conversions_of_a_whole_chain_have_their_history():
    episodes = [_old_conversion(0), _old_conversion(1), _old_conversion(2, reconfigured=True), _old_conversion(3)]
    assert [_indices(episodes, i) for i in range(4)] == [[], [0], [], [2]]
