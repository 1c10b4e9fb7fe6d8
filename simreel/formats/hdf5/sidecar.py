"""ManiSkill's JSON sidecar beside an HDF5 recording, so ManiSkill's own tools (`replay_trajectory`, its
dataset loaders) read simreel files. simreel itself never needs it: the `.h5` is self-describing."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from simreel.episode import EpisodeMeta, RecordingMeta, json_default
from simreel.formats.hdf5.layout import sidecar_path
from simreel.formats.targets import write_text_atomic

__all__ = ["sidecar_document", "write_sidecar"]


def sidecar_document(meta: RecordingMeta, episodes: list[EpisodeMeta]) -> dict[str, Any]:
    """The sidecar's JSON: `env_info` (env id, gym.make kwargs, time limit) and one entry per episode."""
    env_kwargs = {
        **meta.env_kwargs,
        "obs_mode": meta.obs_mode,
        "control_mode": meta.control_mode,
        "sim_backend": meta.sim_backend,
        "render_backend": meta.render_backend,
        "reward_mode": meta.reward_mode,
    }
    return {
        "env_info": {
            "env_id": meta.env_id,
            "env_kwargs": {k: v for k, v in env_kwargs.items() if v is not None},
            "max_episode_steps": meta.max_episode_steps,
        },
        "source_type": "simreel",
        "source_desc": meta.command,
        "episodes": [_episode_entry(meta, e) for e in episodes],
    }


def _episode_entry(meta: RecordingMeta, e: EpisodeMeta) -> dict[str, Any]:
    return {
        "episode_id": e.index,
        "episode_seed": e.seed,
        "reset_kwargs": {"seed": e.seed, **({"options": e.reset_options} if e.reset_options else {})},
        "control_mode": meta.control_mode,
        "elapsed_steps": e.length,
        "success": e.success,
    }


def write_sidecar(path: Path, meta: RecordingMeta, episodes: list[EpisodeMeta]) -> None:
    """(Re)write the sidecar of the recording `path` atomically."""
    doc = sidecar_document(meta, episodes)
    write_text_atomic(sidecar_path(path), json.dumps(doc, indent=2, default=json_default))
