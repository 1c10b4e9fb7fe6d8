"""Reproducing an episode's reset (`simreel.sim.rebuild.reset_to_episode`, which replay, view and convert share) and
building with a render-device fallback, on a fake env that records what it is asked."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from simreel.errors import RenderUnavailableError
from simreel.model.meta import EpisodeMeta
from simreel.sim.rebuild import GYM_MAKE_SEED, build_with_render_fallback, reset_to_episode


class FakeEnv:
    """Records reset calls; `reconfigures` makes the next plain reset report a reconfiguration."""

    def __init__(self, *, reconfiguration_freq: int = 0, reconfigures: bool = False) -> None:
        self.calls: list[tuple] = []
        self.reconfigures = reconfigures
        self.unwrapped = SimpleNamespace(reconfiguration_freq=reconfiguration_freq, _reconfig_counter=0)

    def reset(self, *, seed=None, options=None):
        self.calls.append((seed, options))
        rebuilt = bool(options and options.get("reconfigure")) or self.reconfigures
        return None, {"reconfigure": rebuilt}


@pytest.mark.parametrize(
    ("meta", "scene_seed", "calls", "now"),
    [
        # gym.make's scene of sub-scene 0 is already there: only the episode's own reset
        (EpisodeMeta(0, seed=5), GYM_MAKE_SEED, [(5, None)], GYM_MAKE_SEED),
        # sub-scene 1 of a batched recording ran in gym.make's scene built with seed 2022 + 1
        (EpisodeMeta(1, seed=5, env_idx=1), GYM_MAKE_SEED, [(2023, {"reconfigure": True}), (5, None)], 2023),
        (EpisodeMeta(2, seed=6, env_idx=1), 2023, [(6, None)], 2023),
        # a per-episode scene of a heterogeneous task; options pass through, env_idx does not
        (EpisodeMeta(3, seed=7, scene_seed=4, reset_options={"env_idx": [0], "x": 1}), GYM_MAKE_SEED,
         [(4, {"reconfigure": True}), (7, {"x": 1})], 4),
        # an unknown scene (a caller's env, a first episode) is always rebuilt
        (EpisodeMeta(4, seed=8), None, [(2022, {"reconfigure": True}), (8, None)], 2022),
        # the recorded reset rebuilt the scene itself
        (EpisodeMeta(5, seed=9, reconfigured=True, scene_seed=9), 4, [(9, {"reconfigure": True})], 9),
    ],
)
def test_the_scene_is_rebuilt_only_when_it_differs(meta, scene_seed, calls, now):
    env = FakeEnv()
    done = reset_to_episode(env, meta, scene_seed=scene_seed)
    assert env.calls == calls
    assert done.scene_seed == now
    assert done.scene_builds == sum(bool(o and o.get("reconfigure")) for _, o in calls)
    assert done.limits == []


def test_periodic_reconfiguration_is_held_off_and_limits_are_named():
    env = FakeEnv(reconfiguration_freq=2)
    done = reset_to_episode(env, EpisodeMeta(0, seed=None), scene_seed=GYM_MAKE_SEED)
    assert env.unwrapped._reconfig_counter == 1  # the recorded reset did not reconfigure
    assert done.limits == ["the episode has no seed: its reset cannot be reproduced"]
    env = FakeEnv(reconfigures=True)
    done = reset_to_episode(env, EpisodeMeta(0, seed=3), scene_seed=GYM_MAKE_SEED)
    assert done.scene_seed == 3 and done.scene_builds == 1
    assert done.limits == ["the reset reconfigured the scene, the recorded one did not"]


def test_render_fallback_corrects_only_a_default_of_none():
    tried = []

    def build(render: str) -> str:
        tried.append(render)
        if render == "none":
            raise RenderUnavailableError("needs a render device")
        return f"env({render})"

    assert build_with_render_fallback(build, "none") == ("env(auto)", "auto")
    assert tried == ["none", "auto"]

    def no_device(render: str) -> str:
        raise RenderUnavailableError(f"no device for {render}")

    with pytest.raises(RenderUnavailableError, match="no device for auto"):
        build_with_render_fallback(no_device, "auto")  # not retried


def test_an_unseeded_reset_runs_with_its_generators_and_another_episode_drops_them():
    """The episode's own reset runs with its recorded generator states set (the process's put back after); the
    other episode `another_episode` makes is seeded, so it carries none."""
    import torch

    from simreel.sim.generators import capture_generators, consumed_generators
    from simreel.sim.rebuild import another_episode

    before = capture_generators()
    drawn = torch.rand(2).tolist()
    states = consumed_generators(before)
    seen = []

    class Drawing(FakeEnv):
        def reset(self, *, seed=None, options=None):
            seen.append(torch.rand(2).tolist())
            return super().reset(seed=seed, options=options)

    ours = capture_generators()
    done = reset_to_episode(Drawing(), EpisodeMeta(1, seed=None, reset_generators=states), scene_seed=GYM_MAKE_SEED)
    assert seen == [drawn] and capture_generators() == ours
    assert done.limits == [] and done.notes == ["reset without a seed, its random generators (torch) set to their "
                                                "recorded states"]
    assert another_episode(EpisodeMeta(1, seed=None, reset_generators=states)).reset_generators == {}
