"""`RecordWrapper`'s checks of what it is given: the wrappers below it, its options, reset seeds. Each refusal is one
line naming the fix, raised before anything is written (the folder stays empty)."""

from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
import pytest
from support.children import child_pids, wait_ended

from simreel.cli.main import main
from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.recorders import RecordWrapper
from simreel.sim.make import make_env

ABOVE = "; a replay could not reproduce the recording. Put {0} above RecordWrapper: {0}(RecordWrapper(env, ...), ...)"


def _action_repeat(env):
    from mani_skill.utils.wrappers import ActionRepeatWrapper

    return ActionRepeatWrapper(env, repeat=3)


def _cached_reset(env):
    from mani_skill.utils.wrappers import CachedResetWrapper

    return CachedResetWrapper(env)


def _cpu_gym(env, **kwargs):
    from mani_skill.utils.wrappers import CPUGymWrapper

    return CPUGymWrapper(env, **kwargs)


def _frame_stack(env):
    from mani_skill.utils.wrappers import FrameStack

    return FrameStack(env, num_stack=2)


@pytest.mark.parametrize(
    ("wrap", "record_obs", "name", "change"),
    [
        (_action_repeat, False, "ActionRepeatWrapper", "steps the task several times in one step()"),
        (_cached_reset, False, "CachedResetWrapper",
         "resets the task to cached states, not to the state its seed gives"),
        (_cpu_gym, True, "CPUGymWrapper",
         "unbatches the task's observations (record_obs=True records them with their env axis)"),
        (lambda env: _cpu_gym(env, ignore_terminations=True), False, "CPUGymWrapper",
         "reports the task's terminated steps as not terminated (ignore_terminations=True)"),
        (_frame_stack, True, "FrameStack", "changes the task's observations"),
        (lambda env: gym.wrappers.RepeatAction(env, 2), False, "RepeatAction",
         "steps the task several times in one step()"),
        (lambda env: gym.wrappers.TransformReward(env, lambda r: 2 * r), False, "TransformReward",
         "changes the task's rewards"),
        (lambda env: gym.wrappers.NormalizeReward(env), False, "NormalizeReward", "changes the task's rewards"),
    ],
    ids=["ActionRepeat", "CachedReset", "CPUGym-obs", "CPUGym-ignore_terminations", "FrameStack-obs", "RepeatAction",
         "TransformReward", "NormalizeReward"],
)
def test_a_wrapper_below_that_changes_steps_or_resets_is_refused_and_nothing_is_written(tmp_path, wrap, record_obs,
                                                                                        name, change):
    """Below the recorder, ActionRepeatWrapper made every episode diverge at step 0 and CachedResetWrapper every reset
    inconsistent; CPUGymWrapper with record_obs failed at the first reset with an internal layout error and left a
    0-episode file and an empty .partial/ folder."""
    env = wrap(make_env("PickCube-v1", max_episode_steps=10))
    with pytest.raises(UsageError) as refused:
        RecordWrapper(env, tmp_path / "r.h5", record_obs=record_obs)
    env.close()
    assert str(refused.value) == f"RecordWrapper wraps {name}, which {change}" + ABOVE.format(name)
    assert list(tmp_path.iterdir()) == []


def test_the_neutral_wrappers_below_are_accepted_and_their_recording_replays_exact(tmp_path, capsys):
    """A guard for the rule above: wrappers that leave steps and resets as the task's stay accepted (make_env's
    TimeLimit, OrderEnforcing and PassiveEnvChecker; ManiSkill's RecordEpisode and CPUGymWrapper without recorded
    observations; RecordEpisodeStatistics; FlattenObservation without recorded observations; another RecordWrapper),
    and what is recorded through them replays exact."""
    from mani_skill.utils.wrappers import RecordEpisode

    env = RecordEpisode(make_env("PickCube-v1", max_episode_steps=4), str(tmp_path / "ms"), save_video=False)
    env = RecordWrapper(_cpu_gym(env), tmp_path / "inner.h5", contacts="none")
    env = gym.wrappers.FlattenObservation(gym.wrappers.RecordEpisodeStatistics(env))
    with RecordWrapper(env, tmp_path / "outer.h5", contacts="none") as rec:
        for seed in (1, 2):
            rec.reset(seed=seed)
            for _ in range(4):
                rec.step(rec.action_space.sample())
    for path in ("inner.h5", "outer.h5"):
        assert main(["replay", str(tmp_path / path)]) == 0, capsys.readouterr()
        assert "2 of 2 episode(s) verified (2 exact" in capsys.readouterr().out


# ------------------------------------------------------------------ options


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"contacts": 123}, 'contacts=123: give "auto", "none", or contact pairs as a string '
                            '"panda/panda_leftfinger:cube,cube:table-workspace" or a list of "A:B" strings'),
        ({"block_steps": "x"}, "block_steps='x': give the number of steps to buffer, an int ≥ 1 (default 256)"),
        ({"block_steps": True}, "block_steps=True: give the number of steps to buffer, an int ≥ 1 (default 256)"),
        ({"writer_options": {"nope": 1}},
         "writer_options nope: not an option of the HDF5 writer, which takes compression"),
        ({"writer_options": ["compression"]},
         "writer_options=['compression']: give a dict of the format's writer options, e.g. {\"compression\": \"gzip\"}"),
        ({"imports": ("simreel_no_such_tasks.py",)},
         "imports: simreel_no_such_tasks.py: no such file ({tmp}/simreel_no_such_tasks.py); name the .py file that "
         "registers the task"),
        ({"imports": ("simreel_no_such_tasks",)},
         "imports: simreel_no_such_tasks: no module of that name on sys.path or in {tmp}; name the module or the .py "
         "file that registers the task"),
        ({"imports": 7}, "imports=7: give the .py files or modules that register the task, as a tuple of strings, "
                         "e.g. (\"my_tasks.py\",)"),
        ({"command": 5}, "command=5: give the command line as a string (stored for provenance)"),  # was: a file
        ({"overwrite": "no"}, "overwrite='no': give True or False"),  # that could not be read back; a truthy "no"
        ({"record_obs": 1}, "record_obs=1: give True or False"),
        ({"poses": "yes"}, "poses='yes': give True or False"),
        ({"writer_process": None}, "writer_process=None: give True or False"),
    ],
    ids=["contacts-int", "block_steps-str", "block_steps-bool", "writer_options-unknown", "writer_options-list",
         "imports-missing-file", "imports-missing-module", "imports-int", "command-int", "overwrite-str",
         "record_obs-int", "poses-str", "writer_process-none"],
)
def test_a_bad_option_is_one_usage_error_and_nothing_is_written(tmp_path, monkeypatch, options, message):
    """From Python these were AttributeError (contacts=123), TypeError (block_steps="x", an unknown writer option),
    or accepted (an import found nowhere, which replay then called moved)."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    env = make_env("PushCube-v1")
    with pytest.raises(UsageError) as refused:
        RecordWrapper(env, out / "r.h5", **options)
    env.close()
    assert str(refused.value) == message.replace("{tmp}", str(tmp_path))
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("writer_process", [True, False], ids=["writer-process", "in-process"])
def test_a_compression_the_hdf5_writer_does_not_take_is_one_usage_error_and_leaves_nothing_behind(tmp_path,
                                                                                               writer_process):
    """Regression: a plain ValueError from the HDF5 writer (MCAP's was a UsageError). Refused, the recorder leaves no
    file, no NAME.partial folder and no writer process behind."""
    before = set(child_pids(os.getpid()))
    env = make_env("PushCube-v1")
    with pytest.raises(UsageError) as refused:
        RecordWrapper(env, tmp_path / "r.h5", writer_options={"compression": "bogus"}, writer_process=writer_process)
    env.close()
    assert str(refused.value) == "unknown HDF5 compression 'bogus'; use one of gzip, lzf, None"
    wait_ended([pid for pid in child_pids(os.getpid()) if pid not in before])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("path", "options", "message"),
    [
        (5, None, "path=5: give the file to record to, a str or pathlib.Path ending in .h5 or .mcap"),  # was: TypeError
        ("r.h5", {"contacts": "none"}, "options={'contacts': 'none'}: give a RecordOptions, or its fields as keywords, "
                                       'e.g. RecordWrapper(env, path, contacts="none")'),  # was: TypeError
    ],
    ids=["path-int", "options-dict"],
)
def test_a_path_or_options_of_the_wrong_type_is_one_usage_error(tmp_path, monkeypatch, path, options, message):
    monkeypatch.chdir(tmp_path)
    before = set(child_pids(os.getpid()))
    env = make_env("PushCube-v1")
    with pytest.raises(UsageError) as refused:
        RecordWrapper(env, path, options)
    env.close()
    assert str(refused.value) == message
    assert [pid for pid in child_pids(os.getpid()) if pid not in before] == []  # refused before the writer starts
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_writer_option_for_mcap_names_the_mcap_options(tmp_path):
    env = make_env("PushCube-v1")
    with pytest.raises(UsageError, match="^writer_options nope: not an option of the MCAP writer, which takes "
                                         "compression, chunk_size, fsync$"):
        RecordWrapper(env, tmp_path / "r.mcap", writer_options={"nope": 1, "fsync": True})
    env.close()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("writer_process", [True, False], ids=["writer-process", "in-process"])
def test_an_mcap_writer_option_of_the_wrong_value_is_refused_before_the_writer_starts(tmp_path, writer_process):
    """Regression: chunk_size="1M" was a raw TypeError inside mcap's writer, after the writer process had started;
    chunk_size=0 wrote one chunk per message, fsync="no" counted as yes."""
    before = set(child_pids(os.getpid()))
    env = make_env("PushCube-v1")
    for options, message in [({"chunk_size": "1M"}, "chunk_size='1M': give the bytes of messages per chunk, an int "
                                                     ">= 1 (default 1 MiB)"),
                             ({"fsync": "no"}, "fsync='no': give True or False")]:
        with pytest.raises(UsageError) as refused:
            RecordWrapper(env, tmp_path / "r.mcap", writer_options=options, writer_process=writer_process)
        assert str(refused.value) == message
    env.close()
    assert [pid for pid in child_pids(os.getpid()) if pid not in before] == []
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_keyword_names_the_options(tmp_path):
    env = make_env("PushCube-v1")
    with pytest.raises(UsageError, match="^foo=1: give only the options RecordOptions has: contacts, record_obs, poses, "
                                         "overwrite, "):
        RecordWrapper(env, tmp_path / "r.h5", foo=1)
    env.close()
    assert list(tmp_path.iterdir()) == []


def test_contact_pairs_as_a_list_are_recorded_as_the_same_pairs_joined(tmp_path):
    """The natural Python form: ``contacts=["cube:table-workspace", ...]`` (was AttributeError: 'list' object has no
    attribute 'strip')."""
    with RecordWrapper(make_env("PushCube-v1"), tmp_path / "r.h5",
                       contacts=["cube:table-workspace", "goal_region:cube"]) as rec:
        rec.reset(seed=0)
        rec.step(np.zeros(rec.action_space.shape, np.float32))
    assert rec.spec.additional_wrappers[-1].kwargs["contacts"] == "cube:table-workspace,goal_region:cube"
    with open_reader(tmp_path / "r.h5") as r:
        pairs = [ch.bodies for ch in r.meta.contact_channels if ch.kind == "pair"]
    assert pairs == [("cube", "table-workspace"), ("goal_region", "cube")]


def test_an_import_found_now_is_recorded_by_its_absolute_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_noop_tasks.py").write_text("")
    with RecordWrapper(make_env("PushCube-v1"), tmp_path / "r.h5", imports="my_noop_tasks.py") as rec:
        rec.reset(seed=0)
        rec.step(np.zeros(rec.action_space.shape, np.float32))
    with open_reader(tmp_path / "r.h5") as r:
        assert r.meta.imports == [str(tmp_path / "my_noop_tasks.py")]


# ------------------------------------------------------------------ seeds


def test_a_seed_list_of_another_length_is_refused_before_the_env_resets(tmp_path):
    """ManiSkill 3.0.1 takes reset(seed=[1, 2]) on a 1-env task as the episode seeds of two envs: the episode was
    recorded with seed None. Refused, the running episode goes on untouched; a one-seed list is that seed."""
    rec = RecordWrapper(make_env("PushCube-v1"), tmp_path / "r.h5")
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    rec.step(zero)
    with pytest.raises(UsageError, match=r"^reset\(seed=\.\.\.\) got 2 seeds for 1 env\(s\); give one seed, or a list "
                                         r"of one seed per env \(1\)$"):
        rec.reset(seed=[1, 2])
    rec.step(zero)
    rec.reset(seed=[4])
    rec.step(zero)
    rec.close()
    with open_reader(tmp_path / "r.h5") as r:
        assert [(m.seed, m.length) for m in r.episodes] == [(0, 2), (4, 1)]


SEED_RANGE = "ManiSkill takes seeds from 0 to 4294967295"


@pytest.mark.parametrize(
    ("reset", "message"),
    [
        ({"seed": "abc"}, f"reset(seed='abc'): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": 1.5}, f"reset(seed=1.5): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": -1}, f"reset(seed=-1): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": 2**70}, f"reset(seed={2**70}): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": {}}, f"reset(seed={{}}): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": True}, f"reset(seed=True): {SEED_RANGE}; give one such int, or a list of one per env (1)"),
        ({"seed": np.array([2**32])}, f"reset(seed=...) holds 4294967296: {SEED_RANGE}; give ints in that range, one "
                                      "seed or a list of one per env (1)"),
        ({"options": {"env_idx": 0}}, "reset(options={'env_idx': 0}): give a list of the envs to reset, from 0 to 0, "
                                      "e.g. {'env_idx': [0]} (ManiSkill takes no single index)"),
        ({"options": [1]}, "reset(options=[1]): give a dict of reset options, e.g. {'env_idx': [0]} or "
                           "{'reconfigure': True}"),
    ],
    ids=["str", "float", "negative", "2**70", "dict", "bool", "2**32-in-array", "scalar-env_idx", "options-list"],
)
def test_a_bad_seed_or_reset_option_is_refused_before_the_running_episode_ends(tmp_path, reset, message):
    """Regression: these failed inside ManiSkill's reset (numpy's or ManiSkill's raw errors) after the running episode
    had been ended and committed, and with the writer process `episodes_committed` did not list it. Refused first,
    the episode goes on, and a correct reset afterwards commits it."""
    rec = RecordWrapper(make_env("PushCube-v1"), tmp_path / "r.h5", contacts="none")
    zero = np.zeros(rec.action_space.shape, np.float32)
    rec.reset(seed=0)
    rec.step(zero)
    with pytest.raises(UsageError) as refused:
        rec.reset(**reset)
    assert str(refused.value) == message
    rec.step(zero)
    rec.reset(seed=2**32 - 1)  # the largest seed ManiSkill takes
    assert [(m.seed, m.length) for m in rec.episodes_committed] == [(0, 2)]
    rec.step(zero)
    rec.close()
    with open_reader(tmp_path / "r.h5") as r:
        assert [(m.seed, m.length) for m in r.episodes] == [(0, 2), (2**32 - 1, 1)]
