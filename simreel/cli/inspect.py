"""`simreel inspect`: what a recording holds — episodes, state layout, contacts, metadata, versions — and, for
files simreel did not write (ManiSkill's own), what they do not hold."""

from __future__ import annotations

import argparse
import json
from typing import Any

__all__ = ["add_parser", "run", "summarize"]


def add_parser(sub: Any) -> None:
    p = sub.add_parser("inspect", help="summarize a recording (.h5 or .mcap, simreel's or ManiSkill's)",
                       description="Print episodes, lengths, success, state layout, contact channels and metadata, "
                                   "and what the file does not hold.")
    p.add_argument("path", metavar="PATH")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(run=run)


def summarize(reader: Any) -> dict[str, Any]:
    """The JSON-able summary `inspect --json` prints."""
    m = reader.meta
    return {
        "path": str(reader.path),
        "meta": m.to_json(),
        "episodes": [e.to_json() for e in reader.episodes],
        "total_steps": sum(e.length for e in reader.episodes),
        "unfinished": list(getattr(reader, "unfinished", [])),
        "notes": list(getattr(reader, "notes", [])),
    }


def _hz(freq: float | None) -> str:
    return "?" if freq is None else f"{freq:g}"  # files written through the API may lack frequencies


def _print_header(reader: Any) -> None:
    m = reader.meta
    print(f"{reader.path}  ({reader.kind})")
    if m.source:
        print("  source     " + ", ".join(f"{k} {v}" for k, v in m.source.items()))
    print(f"  env        {m.env_id}  obs={m.obs_mode} control={m.control_mode} reward={m.reward_mode}")
    print(f"  sim        {m.sim_backend}, num_envs={m.num_envs}, {_hz(m.sim_freq)} Hz sim / {_hz(m.control_freq)} Hz control,"
          f" render={m.render_backend}, max_episode_steps={m.max_episode_steps}")
    if m.env_kwargs:
        print(f"  env kwargs {json.dumps(m.env_kwargs)}")
    if m.imports:
        print(f"  imports    {' '.join(m.imports)}")
    if m.versions:
        print("  versions   " + ", ".join(f"{k} {v}" for k, v in m.versions.items()))
    if m.created_utc or m.command:
        print(f"  recorded   {m.created_utc}  {m.command}".rstrip())
    if m.unknown:
        print(f"  unknown    not in the file: {', '.join(m.unknown)}")


def _print_episodes(reader: Any) -> None:
    eps = reader.episodes
    succ = sum(1 for e in eps if e.success)
    print(f"\nepisodes: {len(eps)}, steps: {sum(e.length for e in eps)}, successful at the end: {succ}")
    print(f"  {'index':>5} {'env':>4} {'seed':>11} {'steps':>6} {'success':>8}  reset")
    for e in eps:
        reset = "reconfigured" if e.reconfigured else ""
        if e.reset_options:
            reset += f" options={json.dumps(e.reset_options)}"
        print(f"  {e.index:>5} {e.env_idx:>4} {e.seed!s:>11} {e.length:>6} {e.success!s:>8}  {reset.strip()}")
        for note in e.notes:
            print(f"  {'':>5} note: {note}")


def _print_layouts(m: Any) -> None:
    print(f"\nstate layout ({len(m.state_layout)} keys, per env):")
    for path, spec in m.state_layout.items():
        print(f"  env_states/{path:<40} {spec.shape!s:<10} {spec.dtype}")
    if m.obs_layout:
        print(f"observations ({len(m.obs_layout)} keys):")
        for path, spec in m.obs_layout.items():
            print(f"  obs/{path:<47} {spec.shape!s:<10} {spec.dtype}")
    print(f"info: {', '.join(m.info_layout) or 'none'}")
    nets = [c.name for c in m.contact_channels if c.kind == "net"]
    pairs = [c.name for c in m.contact_channels if c.kind == "pair"]
    print(f"contacts: {len(nets)} net-force bodies, {len(pairs)} pairs" + (f": {', '.join(pairs)}" if pairs else ""))
    merged = [n for kind in ("actors", "articulations") for n, d in m.scene.get(kind, {}).items() if d.get("merged")]
    if merged:
        print(f"merged views: {', '.join(merged)}")


def _print_tools(reader: Any) -> None:
    from simreel.formats.maniskill.layout import maniskill_tools
    from simreel.formats.mcap.reader import McapReader

    print("ManiSkill tools: " + "; ".join(maniskill_tools(reader.meta, hdf5=not isinstance(reader, McapReader))))


def _print_text(reader: Any) -> None:
    _print_header(reader)
    _print_episodes(reader)
    _print_layouts(reader.meta)
    _print_tools(reader)
    for note in getattr(reader, "notes", []):
        print(f"note: {note}")
    unfinished = getattr(reader, "unfinished", [])
    if unfinished:
        print(f"\nwarning: {len(unfinished)} episode(s) were still running when the recording process stopped and "
              f"were not committed: {', '.join(unfinished)}")


def run(args: argparse.Namespace) -> int:
    from simreel.formats import open_reader

    with open_reader(args.path) as reader:
        if args.json:
            print(json.dumps(summarize(reader), indent=2))
        else:
            _print_text(reader)
    return 0
