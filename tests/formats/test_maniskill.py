"""ManiSkill's own trajectory files, made here with ManiSkill's own tools (RecordEpisode, replay_trajectory):
read as they are, what they lack reported unknown, their quirks named, bad sidecars refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from support.maniskill_files import copy_recording, edit_sidecar, record_maniskill, replay_maniskill

from simreel.cli.main import main
from simreel.errors import RecordingFileError
from simreel.formats import open_reader
from simreel.formats.maniskill.reader import ALWAYS_UNKNOWN, ManiskillReader
from simreel.replay import verify_recording
from simreel.replay.convert.convert import convert_recording


@pytest.fixture(scope="module")
def ms_dir(tmp_path_factory) -> Path:
    """PickCube-v1 demos the way ManiSkill's are published (pd_joint_pos, obs none, env states), with state
    observations, as nested state_dict observations, and without env states or rewards."""
    folder = tmp_path_factory.mktemp("maniskill")
    record_maniskill(folder, "PickCube-v1", name="demos", episodes=2, steps=15)
    record_maniskill(folder, "PickCube-v1", name="state", episodes=1, steps=10, obs_mode="state",
                     source_type="scripted", source_desc="joint-space random walks")
    record_maniskill(folder, "PickCube-v1", name="state_dict", episodes=1, steps=5, obs_mode="state_dict")
    record_maniskill(folder, "PickCube-v1", name="bare", episodes=1, steps=10, record_env_state=False,
                     record_reward=False)
    return folder


def test_a_recordepisode_file_is_read_as_it_is(ms_dir):
    path = ms_dir / "demos.h5"
    with open_reader(path) as r:
        assert isinstance(r, ManiskillReader) and r.kind == "ManiSkill trajectory file (JSON sidecar demos.json)"
        m = r.meta
        assert (m.env_id, m.obs_mode, m.control_mode, m.max_episode_steps, m.num_envs) == (
            "PickCube-v1", "none", "pd_joint_pos", 50, 1)
        assert m.action_space == {"shape": [8], "dtype": "float32"}
        assert set(m.state_layout) == {"actors/cube", "actors/goal_site", "actors/table-workspace",
                                       "articulations/panda"}
        assert m.unknown == [*ALWAYS_UNKNOWN, "fail"]  # PickCube reports no fail
        assert [(e.index, e.seed, e.length, e.reconfigured) for e in r.episodes] == [(0, 0, 15, None), (1, 1, 15, None)]
        ep = r.read_episode(1)
    with h5py.File(path, "r") as f:
        raw = f["traj_1"]
        np.testing.assert_array_equal(ep.actions, raw["actions"][()])
        np.testing.assert_array_equal(ep.rewards, raw["rewards"][()])
        np.testing.assert_array_equal(ep.success, raw["success"][()])
        np.testing.assert_array_equal(ep.env_states["articulations/panda"], raw["env_states/articulations/panda"][()])
    assert ep.fail is None and ep.contact_forces is None and ep.meta.notes == []


def test_observations_as_one_array_and_as_a_nested_dict(ms_dir):
    with open_reader(ms_dir / "state.h5") as r:
        assert list(r.meta.obs_layout) == ["state"] and r.meta.obs_layout["state"].shape == (42,)
        assert r.read_episode(0).obs["state"].shape == (11, 42)
        assert r.meta.source["source_type"] == "scripted" and r.meta.command == "joint-space random walks"
    with open_reader(ms_dir / "state_dict.h5") as r:
        assert {"agent/qpos", "extra/tcp_pose", "extra/is_grasped"} <= set(r.meta.obs_layout)
        assert r.read_episode(0).obs["extra/is_grasped"].dtype == bool


def test_what_a_file_does_not_hold_is_unknown_never_invented(ms_dir, capsys):
    with open_reader(ms_dir / "bare.h5") as r:
        assert {"rewards", "env_states"} <= set(r.meta.unknown) and r.meta.state_layout == {}
        ep = r.read_episode(0)
        assert ep.rewards is None and ep.env_states == {}
    assert main(["inspect", str(ms_dir / "bare.h5")]) == 0
    out = capsys.readouterr().out
    assert "unknown    not in the file: versions, sim_config" in out and "rewards" in out
    assert main(["replay", str(ms_dir / "bare.h5"), "-q"]) == 2  # its flags alone would verify nothing
    assert "a replay could compare only its flags (terminated, truncated, success)" in capsys.readouterr().err
    assert main(["replay", str(ms_dir / "bare.h5"), "-q", "--mode", "step"]) == 2
    assert "--mode step restores recorded states" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("make_bad", "message"),
    [
        (lambda p: p.with_suffix(".json").unlink(),
         "a ManiSkill trajectory file (traj_N groups) without its JSON sidecar: {json} is missing"),
        (lambda p: p.with_suffix(".json").write_text("{not json"), "{json}: unreadable ManiSkill sidecar"),
        (lambda p: edit_sidecar(p, lambda d: d.update(env_info=None)), "{json}: a ManiSkill sidecar without env_info.env_id"),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"].append({**d["episodes"][0], "episode_id": 7})),
         "{json}: lists episodes the .h5 does not hold (traj_7)"),
        (lambda p: edit_sidecar(p, lambda d: d.update(episodes={})), "{json}: a ManiSkill sidecar whose `episodes` is not"),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"][1].update(episode_id="x")),
         '{json}: episodes[1].episode_id is "x", expected a whole number'),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"][1].update(episode_id=-1)),
         "{json}: episodes[1].episode_id is -1, expected a whole number >= 0"),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"][1].update(elapsed_steps="abc")),
         '{json}: episodes[1].elapsed_steps is "abc", expected a whole number'),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"][1]["reset_kwargs"].update(options="x")),
         '{json}: episodes[1].reset_kwargs.options is "x", expected an object'),
        (lambda p: edit_sidecar(p, lambda d: d["env_info"]["env_kwargs"].update(num_envs="two")),
         '{json}: env_info.env_kwargs.num_envs is "two", expected a whole number'),
        (lambda p: edit_sidecar(p, lambda d: d["episodes"][1].update(episode_id=0)),
         "{json}: lists traj_0 more than once: a sidecar lists each episode once"),
        (lambda p: edit_sidecar(p, lambda d: d["env_info"].update(max_episode_steps=-1)),  # was: replay "diverged"
         "{json}: env_info.max_episode_steps is -1, expected a whole number >= 1 or null"),
        (lambda p: edit_sidecar(p, lambda d: d["env_info"].update(max_episode_steps="x")),  # was: read as no limit
         '{json}: env_info.max_episode_steps is "x", expected a whole number >= 1 or null'),
    ],
    ids=["missing", "not-json", "no-env-info", "episode-not-in-h5", "episodes-not-a-list", "episode-id-not-a-number",
         "episode-id-negative", "elapsed-steps-not-a-number", "options-not-an-object", "num-envs-not-a-number",
         "episode-listed-twice", "time-limit-negative", "time-limit-not-a-number"],
)
def test_a_missing_or_mismatching_sidecar_is_one_line(ms_dir, tmp_path, capsys, make_bad, message):
    path = copy_recording(ms_dir, "demos", tmp_path)
    make_bad(path)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message.format(json=path.with_suffix(".json")) in err, err


def test_an_episode_id_given_as_a_digit_string_is_read_as_maniskills_tools_read_it(ms_dir, tmp_path):
    path = copy_recording(ms_dir, "demos", tmp_path)
    edit_sidecar(path, lambda d: d["episodes"][1].update(episode_id="1"))  # replay_trajectory formats it: traj_1
    with open_reader(path) as r:
        assert [e.index for e in r.episodes] == [0, 1] and r.read_episode(1).length == 15


def test_a_traj_n_that_is_a_dataset_is_refused_in_one_line(ms_dir, tmp_path, capsys):
    path = copy_recording(ms_dir, "demos", tmp_path)
    with h5py.File(path, "a") as f:
        del f["traj_0"]
        f["traj_0"] = np.zeros(3)
    for command in ("inspect", "replay"):
        assert main([command, str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "traj_0 is a dataset, not a group of an episode's arrays" in err, err


def _tamper(path: Path, change) -> None:
    with h5py.File(path, "a") as f:
        change(f)


def _set(f: h5py.File, name: str, value: np.ndarray) -> None:
    del f[name]
    f[name] = value


@pytest.mark.parametrize(
    ("change", "why"),
    [
        (lambda f: [f.__delitem__(f"traj_0/{k}") for k in ("env_states", "success")],
         "traj_1 differs from traj_0 (the first episode, whose datasets set the file's layout): it holds "
         "env_states/actors/cube, env_states/actors/goal_site, env_states/actors/table-workspace, "
         "env_states/articulations/panda, success, which the first lacks"),
        (lambda f: f.__delitem__("traj_1/rewards"),
         "traj_1 differs from traj_0 (the first episode, whose datasets set the file's layout): it lacks rewards"),
        (lambda f: _set(f, "traj_1/actions", f["traj_1/actions"][:, :-1]),
         "traj_1 differs from traj_0 (the first episode, whose datasets set the file's layout): its actions is "
         "float32 (T, 7), the first's float32 (T, 8)"),
    ],
    ids=["first-lacks-what-later-ones-hold", "a-later-one-lacks-one", "another-action-shape"],
)
def test_an_episode_whose_datasets_differ_from_the_first_is_refused_never_read_short(ms_dir, tmp_path, capsys,
                                                                                     change, why):
    """The first episode's datasets are the file's layout (its fields and limits): an episode holding more, fewer
    or other-shaped arrays is an error naming them, never replayed as exact with arrays unchecked nor copied
    losing them."""
    path = copy_recording(ms_dir, "demos", tmp_path)
    _tamper(path, change)
    assert main(["replay", str(path), "-q", "--episodes", "1", "--report", str(tmp_path / "r.json")]) == 2
    episode = json.loads((tmp_path / "r.json").read_text())["episodes"][0]
    assert (episode["verdict"], episode["error"]) == ("error", why)
    assert main(["merge", str(path), "-o", str(tmp_path / "merged.h5")]) == 2
    assert why in capsys.readouterr().err and not (tmp_path / "merged.h5").exists()


def test_an_hdf5_file_of_neither_kind_is_refused(tmp_path, capsys):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["data"] = np.zeros(3)
    assert main(["inspect", str(tmp_path / "other.h5")]) == 2
    assert "neither a simreel recording (no simreel metadata) nor a ManiSkill trajectory file" in capsys.readouterr().err


def test_quirks_of_a_file_are_named(ms_dir, tmp_path):
    path = copy_recording(ms_dir, "demos", tmp_path)

    def change(doc):
        doc["episodes"][0]["reset_kwargs"]["seed"] = [0]  # a seed list, as some ManiSkill versions write it
        doc["episodes"][1]["reset_kwargs"]["seed"] = 5  # not the episode_seed
        doc["episodes"][1]["elapsed_steps"] = 14
        doc["episodes"][1]["control_mode"] = "pd_joint_delta_pos"  # not env_kwargs' pd_joint_pos
        doc["extra_episode_not_listed"] = True

    edit_sidecar(path, change)
    with h5py.File(path, "a") as f:
        f.copy("traj_0", "traj_9")  # a group the sidecar does not list
    with open_reader(path) as r:
        assert r.episodes[0].seed == 0 and "reset_kwargs.seed is a list ([0])" in r.episodes[0].notes[0]
        assert r.episodes[1].seed == 1 and "reset_kwargs.seed 5 is not episode_seed 1" in r.episodes[1].notes[0]
        assert "elapsed_steps 14 in the sidecar, 15 actions in the file" in r.read_episode(1).meta.notes
        assert ("the sidecar lists this episode's control mode as pd_joint_delta_pos, its env_kwargs as pd_joint_pos: "
                "replayed in pd_joint_pos") in r.episodes[1].notes and r.meta.control_mode == "pd_joint_pos"
        assert r.notes == ["1 group(s) the sidecar does not list (traj_9) are skipped, as ManiSkill's tools skip them"]


def test_an_episodes_length_is_the_actions_it_holds_from_the_listing_on(ms_dir, tmp_path, capsys):
    """The listing (what filter, inspect and merge go by) gives each episode the actions its group holds, and notes
    an `elapsed_steps` that says otherwise or nothing, before any episode is opened."""
    path = copy_recording(ms_dir, "demos", tmp_path)
    edit_sidecar(path, lambda doc: (doc["episodes"][0].update(elapsed_steps=3), doc["episodes"][1].pop("elapsed_steps")))
    with open_reader(path) as r:
        assert [(e.length, e.notes) for e in r.episodes] == [
            (15, ["elapsed_steps 3 in the sidecar, 15 actions in the file"]),
            (15, ["the sidecar gives no elapsed_steps; 15 actions in the file"])]
        assert r.read_episode(0).meta.notes == r.episodes[0].notes
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "episodes: 2, steps: 30," in out and "note: elapsed_steps 3 in the sidecar, 15 actions in the file" in out


def test_an_episode_whose_actions_cannot_be_found_leaves_the_rest_readable(ms_dir, tmp_path):
    """Listing the lengths reads one dataset's shape per episode; where it is not there, that episode alone is
    refused when opened, as before, with what is wrong."""
    path = copy_recording(ms_dir, "demos", tmp_path)
    _tamper(path, lambda f: f.__delitem__("traj_1/actions"))
    with open_reader(path) as r:
        assert [e.length for e in r.episodes] == [15, 15] and r.read_episode(0).length == 15
        with pytest.raises(RecordingFileError, match="traj_1 differs from traj_0 .*: it lacks actions"):
            r.open_episode(1)


def test_a_gpu_recording_names_what_it_does_not_hold_and_asks_for_the_cpu_sim(ms_dir, tmp_path, capsys):
    """The sidecar of a GPU-sim recording (physx_cuda, 4 envs: reset_kwargs {}); its arrays here are CPU ones."""
    path = copy_recording(ms_dir, "demos", tmp_path)

    def gpu(doc):
        doc["env_info"]["env_kwargs"].update(sim_backend="physx_cuda", num_envs=4)
        for e in doc["episodes"]:
            e["reset_kwargs"] = {}

    edit_sidecar(path, gpu)
    with open_reader(path) as r:
        assert (r.meta.sim_backend, r.meta.num_envs) == ("physx_cuda", 4)
        assert {"reset_options", "env_idx"} <= set(r.meta.unknown) and r.episodes[0].seed == 0
    assert main(["replay", str(path), "-q"]) == 2
    assert "recorded on the GPU sim (physx_cuda) and this machine has no CUDA device" in capsys.readouterr().err
    assert main(["replay", str(path), "-q", "--sim-backend", "physx_cpu"]) == 0
    out = capsys.readouterr().out
    assert "limit: sub-scenes unknown: ManiSkill does not record which parallel env ran an episode" in out


def test_a_state_mode_output_of_replay_trajectory_is_found_off_by_one(ms_dir, maniskill_env, tmp_path, capsys):
    """replay_trajectory -o state --use-env-states stores the state after step 0 as the first state."""
    converted = replay_maniskill(copy_recording(ms_dir, "demos", tmp_path), maniskill_env, "-o", "state", "--use-env-states")
    with open_reader(converted) as r:
        ep = r.read_episode(0)
        assert not ep.meta.initial_state_known
        assert "as in files replay_trajectory writes with --use-env-states" in ep.meta.notes[0]
        assert {"rewards", "fail"} <= set(r.meta.unknown)  # replay_trajectory records no rewards by default
    with open_reader(ms_dir / "demos.h5") as original:
        np.testing.assert_array_equal(ep.env_states["actors/cube"][0], original.read_episode(0).env_states["actors/cube"][1])
    # checked as it was made (restore, step, compare): the reset row is skipped, step 0 starts from the reset
    assert main(["replay", str(converted), "-q", "--mode", "step"]) == 0
    assert "the reset state is not compared" in capsys.readouterr().out
    assert main(["inspect", "--json", str(converted)]) == 0  # named per episode by inspect too
    assert [e["initial_state_known"] for e in json.loads(capsys.readouterr().out)["episodes"]] == [False, False]


def test_only_the_group_name_maniskill_looks_up_is_an_episodes():
    """ManiSkill's tools open ``traj_<episode_id>``: ``traj_01`` beside ``traj_1`` is no second episode 1."""
    from simreel.formats.maniskill.layout import group_index, group_name

    assert [group_index(n) for n in ("traj_0", "traj_1", "traj_10", "traj_01", "traj_00", "traj_x")] == \
        [0, 1, 10, None, None, None]
    assert all(group_index(group_name(i)) == i for i in (0, 7, 12345))


@pytest.mark.parametrize(
    ("add", "named"),
    [
        (lambda group: group.create_dataset("my_extra", data=np.arange(10)), "my_extra"),
        (lambda group: group.create_dataset("obs_extra_group/z", data=np.zeros((11, 2))), "obs_extra_group/z"),
    ],
    ids=["dataset", "group-of-observations"],
)
def test_datasets_simreel_has_no_place_for_are_refused_by_name_never_dropped(ms_dir, tmp_path, capsys, add, named):
    """Another tool's additions to every episode (here the state file's only one): `inspect` names them, and each
    command that reads the episodes refuses them in one line saying what to do, by the rule of simreel's own .h5
    files, rather than copy the rest and call the copy checked."""
    path = copy_recording(ms_dir, "state", tmp_path)
    with h5py.File(path, "a") as f:
        add(f["traj_0"])
    problem = (f"traj_0 holds {named}, which the recording's layout does not list (simreel reads ManiSkill's own "
               "datasets only, and refuses an episode holding others rather than drop them: keep ManiSkill's tools "
               "for this file, or delete them from a copy (h5py: del f['traj_N/<name>']) to use simreel on the rest)")
    assert main(["inspect", str(path)]) == 0
    assert f"note: {problem}\n" in capsys.readouterr().out
    for command in (["merge", str(path), "-o", str(tmp_path / "out.h5")],
                    ["convert", str(path), str(tmp_path / "out.mcap")],
                    ["filter", str(path), "-o", str(tmp_path / "out.h5"), "--min-steps", "1"]):
        assert main(command) == 2, command
        captured = capsys.readouterr()
        assert captured.err.count("\n") == 1 and captured.err.endswith(f"{problem}\n"), captured.err
        assert "checked" not in captured.out
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(("out", ".out"))]


def test_sidecar_keys_simreel_does_not_map_are_kept(ms_dir, tmp_path, capsys):
    """An episode entry's own keys travel in a note on the episode into every copy (a long one is named, with its
    size); the top level's and env_info's in the recording's `source`, as the source type and description do."""
    path = copy_recording(ms_dir, "state", tmp_path)

    def add_keys(doc):
        doc["episodes"][0].update(my_note="keep me", my_big=list(range(100)))
        doc["episodes"][0]["reset_kwargs"]["my_flag"] = True
        doc["my_top"] = {"x": 1}
        doc["env_info"]["my_env_note"] = "v2"

    edit_sidecar(path, add_keys)
    note = ("its sidecar entry holds keys simreel's episode metadata has no field for, kept only in this note (a copy's "
            'sidecar lacks them): my_note="keep me", my_big (390 characters of JSON, not kept), reset_kwargs.my_flag=true')
    assert main(["merge", str(path), "-o", str(tmp_path / "merged.h5"), "-q"]) == 0
    for copy in (path, tmp_path / "merged.h5"):
        with open_reader(copy) as r:
            assert r.episodes[0].notes == [note]
            assert r.meta.source["other_sidecar_keys"] == {"my_top": {"x": 1}, "env_info.my_env_note": "v2"}
            assert (r.meta.source["source_type"], r.meta.source["source_desc"]) == ("scripted", "joint-space random walks")
    assert main(["inspect", str(tmp_path / "merged.h5")]) == 0
    assert f"note: {note}" in capsys.readouterr().out
    # and the copy's sidecar says where the demos came from, for ManiSkill's tools: not "simreel"
    written = json.loads((tmp_path / "merged.json").read_text())
    assert (written["source_type"], written["source_desc"]) == ("scripted", "joint-space random walks")


def test_a_file_recordepisode_wrote_no_episode_into_is_read_as_empty_not_foreign(tmp_path, capsys):
    """RecordEpisode(save_on_reset=False) whose flush_trajectory() was never called writes no traj_N group and a
    sidecar listing none: an empty ManiSkill file, as inspect says (exit 0); replay says it has no episodes. Before, every
    command called it "neither a simreel recording nor a ManiSkill trajectory file"."""
    path = record_maniskill(tmp_path, "PickCube-v1", name="unflushed", episodes=1, steps=3, save_on_reset=False)
    with h5py.File(path, "r") as f:
        assert list(f) == [] and json.loads(path.with_suffix(".json").read_text())["episodes"] == []
    capsys.readouterr()
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "episodes: 0, steps: 0" in out and "the file holds no episodes: RecordEpisode writes one at each reset and " \
        "at close, or with save_on_reset=False only at each flush_trajectory()" in out, out
    assert main(["replay", str(path), "-q"]) == 2
    assert f"{path}: the recording has no episodes to replay" in capsys.readouterr().err
    for other in ('{"a": 1}', None):  # another tool's JSON beside it, or none: nothing says what the file is
        path.with_suffix(".json").unlink()
        if other:
            path.with_suffix(".json").write_text(other)
        assert main(["inspect", str(path)]) == 2
        assert capsys.readouterr().err == (f"simreel inspect: error: {path}: an HDF5 file that is neither a simreel "
                                           "recording (no simreel metadata) nor a ManiSkill trajectory file (no traj_N "
                                           "groups)\n")


@pytest.mark.parametrize("env_kwargs", [{}, {"enhanced_determinism": True}], ids=["unseeded", "enhanced-determinism"])
def test_an_episode_reset_without_a_seed_has_its_stale_seed_checked_and_replays_from_its_recorded_first_state(
        tmp_path, capsys, env_kwargs):
    """reset() without a seed: ManiSkill 3.0.1 draws the initial state from torch's global RNG, and RecordEpisode still
    writes the env's last seed as episode_seed (a stale seed). The reader keeps it, unchecked; a replay resets with it,
    finds the recorded first state not remade, says "stale seed" naming it, and replays the actions from the recorded
    first state. With enhanced_determinism ManiSkill draws a new seed and uses it: that episode_seed is the reset's."""
    unseeded = not env_kwargs
    path = record_maniskill(tmp_path, "PickCube-v1", name="unseeded", episodes=3, steps=5, obs_mode="state",
                            seeded=False, env_kwargs=env_kwargs)
    entries = json.loads(path.with_suffix(".json").read_text())["episodes"]
    assert ["seed" in e["reset_kwargs"] for e in entries] == [True, False, False]
    with open_reader(path) as r:
        assert [m.seed for m in r.episodes] == [e["episode_seed"] for e in entries]
        assert [m.seed_unchecked for m in r.episodes] == [False, unseeded, unseeded]
        said = [n for m in r.episodes for n in m.notes if n.startswith("reset without a seed")]
    assert len(said) == (2 if unseeded else 0)
    assert not said or said[0] == (
        "reset without a seed (its reset_kwargs hold none): episode_seed 0 may be stale (ManiSkill draws an unseeded "
        "reset from torch's global RNG, and RecordEpisode writes the env's last seed); an actions replay resets with "
        "it and checks it against env_states[0]")
    report = verify_recording(path)
    assert report.episodes[0].verdict == "exact"
    if not unseeded:
        assert [e.verdict for e in report.episodes] == ["exact"] * 3
    for e in report.episodes[1:]:  # from a restored state, PhysX may drift (README: determinism), never off at reset
        assert e.first_divergence is None or e.first_divergence.at != "reset", e.first_divergence
        assert ("actions replayed from the recorded initial state" in e.limits) == unseeded
        assert any(x.startswith("stale seed: a reset with episode_seed 0 did not remake the recorded initial state (")
                   for x in e.limits) == unseeded, e.limits
    if not unseeded:
        return
    capsys.readouterr()
    main(["replay", str(path), "--episodes", "1"])  # the console names it under the episode, whatever its verdict
    assert "note: stale seed: a reset with episode_seed 0 did not remake the recorded initial state" in \
        capsys.readouterr().out
    converted = convert_recording(path, tmp_path / "delta.h5", control_mode="pd_joint_delta_pos")
    for e in converted.episodes[1:]:  # a conversion starts there too: before, from an unseeded reset, objects elsewhere
        assert e.max_abs_error["env_states/actors/goal_site[p]"] == 0.0 and "actions replayed from the recorded " \
            "initial state" in e.limits, (e.max_abs_error, e.limits)


def test_an_episode_reset_without_a_seed_nor_recorded_states_is_an_error_of_that_episode(tmp_path, capsys):
    """Neither its seed nor its first state is known: where it began cannot be told, so it is not replayed nor shown
    from anywhere else (before: an unseeded reset, then "the task's reset is not reproducible"; view drew it)."""
    path = record_maniskill(tmp_path, "PickCube-v1", name="unseeded", episodes=2, steps=3, obs_mode="state",
                            seeded=False, record_env_state=False)
    report = verify_recording(path)
    assert [e.verdict for e in report.episodes] == ["exact", "error"]
    assert report.episodes[1].error == ("episode 1: its reset had no seed and the recording holds no env states, so "
                                        "where it began can be neither remade nor restored: it cannot be replayed")
    capsys.readouterr()
    assert main(["view", str(path), "--episode", "1", "--save", str(tmp_path / "1.rrd")]) == 2
    assert capsys.readouterr().err.endswith("where it began can be neither remade nor restored: its poses cannot be "
                                            "shown\n") and not (tmp_path / "1.rrd").exists()


def test_a_first_step_that_moved_nothing_is_not_said_to_be_replay_trajectorys_off_by_one(tmp_path):
    """RecordEpisode itself, RotateValveLevel0 with the D'Claw held still at first (an idle first step, as a teleop demo
    begins): state rows 0 and 1 are equal, as in replay_trajectory's off-by-one state files. The note said the file was
    one of those, and that it restored the original's state at every step; it says both possibilities now."""
    import gymnasium as gym
    from mani_skill.utils.wrappers.record import RecordEpisode

    env = RecordEpisode(gym.make("RotateValveLevel0-v1", obs_mode="state"), str(tmp_path), trajectory_name="idle",
                        save_video=False)
    env.reset(seed=0)
    for action in (np.zeros(env.action_space.shape), np.full(env.action_space.shape, 0.05)):
        env.step(action)
    env.close()
    with open_reader(tmp_path / "idle.h5") as r:
        notes = r.open_episode(0).meta.notes
    assert len(notes) == 1 and notes[0].startswith("env_states[0] and env_states[1] agree within restore noise "), notes
    assert notes[0].endswith("): the first step moved nothing, or row 0 is the state after step 0 (off by one), as in "
                             "files replay_trajectory writes with --use-env-states or --use-first-env-state; the reset "
                             "state is not compared (--mode step checks a --use-env-states file as it was made: it "
                             "restored the original's state at every step)"), notes
