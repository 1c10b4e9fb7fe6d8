"""`simreel convert`: copy a recording between HDF5 (.h5) and MCAP (.mcap), losslessly, episode by episode."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from simreel.errors import UsageError

__all__ = ["add_parser", "run", "convert"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser(
        "convert",
        help="convert a recording between .h5 and .mcap",
        description="Copy every episode of IN to OUT; the suffix of OUT picks the format (.h5 or .mcap). "
        "Arrays are copied bit-exactly both ways.",
    )
    p.add_argument("input", metavar="IN", help="recording to read (.h5 or .mcap)")
    p.add_argument("output", metavar="OUT", help="file to write: .h5/.hdf5 or .mcap")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--poses", action="store_true",
                   help="when IN has no body poses, compute every actor's and link's world pose by restoring each "
                   "recorded state into the rebuilt env (needs the task; OUT then holds them, so MCAP's /tf "
                   "shows every link)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


class _LinkPoses:
    """Adds `body_poses` of every registry body to episodes, computed in an env rebuilt from the metadata."""

    def __init__(self, meta: Any) -> None:
        from simreel.body_poses import pose_body_names
        from simreel.episode import RecordingMeta
        from simreel.rebuild import env_from_meta

        self._env = env_from_meta(meta, num_envs=1, sim_backend="physx_cpu", render_backend="none")
        self._u = self._env.unwrapped
        self._u.reset(seed=0)
        self._scene_seed: int | None = None
        self.meta = RecordingMeta.from_json(meta.to_json())
        self.meta.pose_bodies = pose_body_names(self._u)

    def add(self, episode: Any) -> Any:
        from simreel.body_poses import body_poses_from_states
        from simreel.rebuild import reset_to_episode

        m = episode.meta  # its scene (per-episode objects of heterogeneous tasks); rebuilt only when it changes
        self._scene_seed = reset_to_episode(self._env, m, scene_seed=self._scene_seed).scene_seed
        episode.body_poses = body_poses_from_states(self._u, self.meta.pose_bodies, episode.env_states)
        return episode

    def close(self) -> None:
        self._env.close()


def convert(src: str | Path, dst: str | Path, *, overwrite: bool = False, quiet: bool = True,
            poses: bool = False) -> tuple[int, int, Any]:
    """Copy every episode of `src` into a new file `dst`; returns (episodes, steps, RecordingMeta of dst).

    `poses`: compute body poses in a rebuilt env when `src` has none (see `--poses`).
    """
    from tqdm import tqdm

    from simreel.formats import check_writable, format_of, open_reader, open_writer, remove_recording

    src_p, dst_p = Path(src), Path(dst)
    format_of(dst_p)  # a bad suffix fails before anything is read
    if src_p.exists() and dst_p.exists() and src_p.resolve() == dst_p.resolve():
        raise UsageError(f"{dst}: IN and OUT are the same file; write to another file")
    check_writable(dst_p, overwrite=overwrite)  # before the reader and the env (--poses) cost anything
    steps = 0
    with open_reader(src_p) as reader:
        for note in getattr(reader, "unfinished", []):
            sys.stderr.write(f"simreel convert: warning: {src}: {note} was never committed and is not copied\n")
        link_poses = _LinkPoses(reader.meta) if poses and not reader.meta.pose_bodies else None
        meta = link_poses.meta if link_poses else reader.meta
        try:
            writer = open_writer(dst_p, meta, overwrite=overwrite)
            try:
                with writer:
                    bar = tqdm(reader.episodes, unit="ep", desc=f"convert {src_p.name}", disable=True if quiet else None,
                               file=sys.stderr)
                    for m in bar:
                        episode = reader.read_episode(m.index)
                        writer.write_episode(link_poses.add(episode) if link_poses else episode)
                        steps += episode.length
            except BaseException:
                remove_recording(dst_p)  # the writer created it: a failed convert leaves no valid-looking file
                raise
        finally:
            if link_poses:
                link_poses.close()
        return len(reader.episodes), steps, meta


def run(args: argparse.Namespace) -> int:
    from simreel.formats import format_of

    episodes, steps, meta = convert(args.input, args.output, overwrite=args.overwrite, quiet=args.quiet,
                                    poses=args.poses)
    size = Path(args.output).stat().st_size
    print(f"converted {episodes} episode(s), {steps} steps, {args.input} → {args.output} ({size / 1024:.0f} KiB)")
    if format_of(args.output) == "mcap" and not meta.pose_bodies:
        print("note: IN has no body poses, so the MCAP transform channel (/tf) shows the actors and articulation "
              "roots of the state dict only; convert with --poses (or record with --poses) for every link")
    return 0
