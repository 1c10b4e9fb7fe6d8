"""Synthetic recordings for the MCAP, convert and dataset tests: arrays a float formatter would damage, no env."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simreel.formats import open_reader, open_writer
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel, EpisodeMeta, RecordingMeta
from simreel.model.state_tree import LeafSpec

ARRAYS = ("actions", "rewards", "terminated", "truncated", "success", "fail", "contact_forces", "body_poses")


def synthetic_meta(*, poses: bool = True) -> RecordingMeta:
    return RecordingMeta(
        env_id="Synthetic-v0",
        control_freq=20.0,
        sim_freq=100.0,
        action_space={"shape": [3], "dtype": "float32", "low": [-1] * 3, "high": [1] * 3},
        state_layout={
            "actors/cube": LeafSpec((13,), "float32"),
            "articulations/robot": LeafSpec((17,), "float32"),
            "goal": LeafSpec((2,), "float64"),
        },
        obs_layout={"agent/qpos": LeafSpec((2,), "float32")},
        info_layout={"is_grasped": LeafSpec((), "bool"), "elapsed_steps": LeafSpec((), "int32")},
        scene={"actors": {"cube": {}}, "articulations": {"robot": {"links": ["base", "arm"]}}},
        contact_channels=[ContactChannel("net", ("cube",)), ContactChannel("pair", ("robot/arm", "cube"))],
        pose_bodies=["cube", "robot/base", "robot/arm"] if poses else [],
    )


def synthetic_episode(meta: RecordingMeta, index: int, T: int, seed: int = 0) -> Episode:
    """Random arrays with the values a float formatter would damage: NaN, -0.0, inf, subnormals."""
    rng = np.random.default_rng(seed + index)

    def floats(shape: tuple[int, ...], dtype: str = "float32") -> np.ndarray:
        a = rng.standard_normal(shape).astype(dtype)
        flat = a.reshape(-1)
        flat[: min(4, flat.size)] = np.array([np.nan, -0.0, np.inf, np.finfo(dtype).smallest_subnormal])[: min(4, flat.size)]
        return a

    B = len(meta.pose_bodies)
    return Episode(
        meta=EpisodeMeta(index=index, seed=100 + index, reset_options={"x": [1, 2]}, length=T, success=bool(index % 2)),
        actions=floats((T, 3)),
        rewards=floats((T,)),
        terminated=rng.random(T) > 0.5,
        truncated=np.zeros(T, bool),
        success=rng.random(T) > 0.5,
        fail=np.zeros(T, bool),
        env_states={"actors/cube": floats((T + 1, 13)), "articulations/robot": floats((T + 1, 17)),
                    "goal": floats((T + 1, 2), "float64")},
        obs={"agent/qpos": floats((T + 1, 2))},
        info={"is_grasped": rng.random(T) > 0.5, "elapsed_steps": np.arange(1, T + 1, dtype=np.int32)},
        contact_forces=floats((T, 2, 3)),
        body_poses=floats((T + 1, B, 7)) if B else None,
    )


def assert_same_episode(got: Episode, want: Episode) -> None:
    """Every array equal byte for byte (NaN included), same dtype and shape; same metadata."""
    assert got.meta == want.meta

    def same(a: np.ndarray | None, b: np.ndarray | None, name: str) -> None:
        assert (a is None) == (b is None), name
        if a is not None:
            assert a.dtype == b.dtype and a.shape == b.shape, (name, a.dtype, b.dtype, a.shape, b.shape)
            assert a.tobytes() == b.tobytes(), name

    for name in ARRAYS:
        same(getattr(got, name), getattr(want, name), name)
    for group in ("env_states", "obs", "info"):
        g, w = getattr(got, group), getattr(want, group)
        assert g.keys() == w.keys(), group
        for k in w:
            same(g[k], w[k], f"{group}/{k}")


def write(path: Path, meta: RecordingMeta, episodes: list[Episode], **options) -> Path:
    with open_writer(path, meta, **options) as w:
        for ep in episodes:
            w.write_episode(ep)
    return path


def sample(path: Path, n: int = 3, **options) -> tuple[Path, list[Episode]]:
    """`n` synthetic episodes of 6 steps, no poses, written to `path` (its suffix picks the format)."""
    meta = synthetic_meta(poses=False)
    episodes = [synthetic_episode(meta, i, 6) for i in range(n)]
    return write(path, meta, episodes, **options), episodes


def long_sample(path: Path, seed: int = 0) -> tuple[Path, list[Episode]]:
    """Episodes of 3, 9000 and 5 steps written to `path`: episode 1 spans three blocks of rows (`block_rows`),
    the unit `convert`, `merge` and `filter` copy at a time."""
    from simreel.formats.base import block_rows

    meta = synthetic_meta()
    episodes = [synthetic_episode(meta, i, T, seed=seed) for i, T in enumerate((3, 9000, 5))]
    write(path, meta, episodes)
    with open_reader(path) as r:
        assert 2 * block_rows(r.open_episode(1).fields) < 9000
    return path, episodes


def only_this_episode_fails(path: Path, episodes: list[Episode], bad: int) -> Exception:
    """Read every episode of `path`: each but `bad` must equal what was written, `bad` must raise
    `RecordingFileError`, which is returned."""
    import pytest

    from simreel.errors import RecordingFileError
    from simreel.formats import open_reader

    with open_reader(path) as r:
        for ep in episodes:
            if ep.meta.index != bad:
                assert_same_episode(r.read_episode(ep.meta.index), ep)
        with pytest.raises(RecordingFileError) as err:
            r.read_episode(bad)
    return err.value
