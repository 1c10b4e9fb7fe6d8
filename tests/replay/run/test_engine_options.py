"""`ReplayerOptions` and `EpisodeReplayer` from Python (`simreel.replay` exports both): a value of the wrong type, an
unknown keyword, metadata that is no `RecordingMeta`, is one `UsageError` naming it and what to give, raised before
the env is built; the documented forms stay valid and one body name is one name."""

from __future__ import annotations

import pytest

import simreel.replay.run.engine as engine
from simreel.errors import UsageError
from simreel.formats import open_reader
from simreel.replay import EpisodeReplayer, ReplayerOptions


@pytest.fixture(scope="module")
def recording(record):
    """A real PickCube-v1 recording's metadata and its first episode (20 steps)."""
    with open_reader(record("PickCube-v1", 2, 20)) as reader:
        return reader.meta, reader.read_episode(0)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"need_obs": "no"}, "need_obs='no': give True or False"),  # was: accepted as yes, observations computed
        ({"need_rewards": 0}, "need_rewards=0: give True or False"),
        ({"obs_mode": 5}, 'obs_mode=5: give an observation mode as a string, e.g. "rgb", or None (the recorded one '
                          "when needed)"),  # was: AttributeError 'int' object has no attribute 'split'
        ({"render_backend": 5}, 'render_backend=5: give a render backend as a string, e.g. "cpu", or None (the one '
                                "the observation mode needs)"),  # was: EnvBuildError ... TypeError from gym.make
        ({"sim_backend": 5}, 'sim_backend=5: give a sim backend as a string, e.g. "physx_cpu", or None (the recorded '
                             "one)"),  # was: the same
        ({"control_mode": 5}, 'control_mode=5: give a control mode as a string, e.g. "pd_ee_delta_pose", or None (the '
                              "recorded one)"),  # was: ManiSkill's AssertionError from gym.make
        ({"pose_bodies": [1]}, 'pose_bodies=[1]: give the names of the bodies whose poses to sample, as a tuple of '
                               'strings, e.g. ("cube", "panda/panda_hand")'),  # was: TypeError at the first reset
        ({"env_kwargs": [1]}, 'env_kwargs=[1]: give the gym.make arguments to add as a dict, e.g. {"shader_dir": '
                              '"rt"}'),  # was: TypeError cannot convert dictionary update sequence element
        ({"bogus": 1}, "bogus=1: give only the options ReplayerOptions has: obs_mode, need_obs, need_rewards, pose_bodies, "
                       "render_backend, sim_backend, control_mode, env_kwargs"),  # was: TypeError
        # ReplayerOptions.__init__() got an unexpected keyword argument 'bogus'
    ],
    ids=["need_obs-str", "need_rewards-int", "obs_mode-int", "render_backend-int", "sim_backend-int",
         "control_mode-int", "pose_bodies-ints", "env_kwargs-list", "unknown"],
)
def test_a_bad_option_is_one_usage_error_before_the_env_is_built(recording, monkeypatch, options, message):
    built = []
    monkeypatch.setattr(engine, "env_from_meta", lambda *a, **k: built.append(a))  # the replayer's env build
    if "bogus" not in options:
        with pytest.raises(UsageError) as refused:
            ReplayerOptions(**options)
        assert str(refused.value) == message
    with pytest.raises(UsageError) as refused:  # the same through EpisodeReplayer's keywords
        EpisodeReplayer(recording[0], **options)
    assert str(refused.value) == message
    assert built == []


@pytest.mark.parametrize(
    ("meta", "options", "message"),
    [
        ("run.h5", None, "meta='run.h5': give the recording's RecordingMeta, e.g. open_reader(path).meta"),  # was:
        # AttributeError 'str' object has no attribute 'obs_mode'
        (None, {"need_obs": True}, "options={'need_obs': True}: give a ReplayerOptions, or its fields as keywords, "
                                   "e.g. EpisodeReplayer(meta, need_obs=True)"),  # was: TypeError replace()
    ],
    ids=["meta-path", "options-dict"],
)
def test_metadata_or_options_of_the_wrong_type_is_one_usage_error(recording, meta, options, message):
    with pytest.raises(UsageError) as refused:
        EpisodeReplayer(meta or recording[0], options)
    assert str(refused.value) == message


def test_one_body_name_is_one_name_and_its_poses_are_sampled(recording):
    """Regression: `pose_bodies="cube"` was four bodies of one letter each, whose poses the replay left out ("the
    rebuilt scene has no b, c, e, u")."""
    meta, episode = recording
    assert ReplayerOptions(pose_bodies=["cube", "panda/panda_hand"]).pose_bodies == ("cube", "panda/panda_hand")
    with EpisodeReplayer(meta, pose_bodies="cube") as replayer:
        replayed = replayer.replay(episode, mode="actions")
    assert not any("body poses" in limit for limit in replayed.limits), replayed.limits
    assert replayed.episode.body_poses.shape[:2] == (episode.length + 1, 1)
