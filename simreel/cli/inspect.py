"""`simreel inspect`: what a recording holds — episodes, state layout, contacts, metadata, versions — what is
wrong with it (damaged episodes, episodes a killed recording left unfinished, side files that lag) and, for files
simreel did not write (ManiSkill's own), what they do not hold."""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

__all__ = ["add_parser", "run", "summarize", "unseeded_counts", "OPENED_EPISODES"]

OPENED_EPISODES = 50
"""How many episodes `inspect FILE` opens, as every command that reads them does, to name what only opening an
episode shows: quirks found in its data (a ManiSkill file's first state off by one: two state rows read), an
episode every command refuses. The first ones only, so that a file of thousands stays fast (an episode opened:
~5 ms); replay, convert, merge and filter open every one."""


def add_parser(sub: Any) -> None:
    p = sub.add_parser("inspect", help="summarize recordings (.h5 or .mcap, simreel's or ManiSkill's)",
                       description="Print episodes, lengths, success, state layout, contact channels and metadata, "
                                   "what the file does not hold and what is wrong with it. Several recordings (files, "
                                   "folders, glob patterns): one line per file and the totals. Exit status 2 when one "
                                   "cannot be read, 1 when part of one is damaged: what the file says of itself (its index, "
                                   "MCAP's checksums); HDF5 data chunks are checked when read (replay, convert, "
                                   "merge), not by inspect.")
    p.add_argument("paths", nargs="+", metavar="PATH", help="recordings, folders of recordings, or glob patterns")
    p.add_argument("--json", action="store_true",
                   help="print the summary as JSON (several recordings: a list, with an error entry for each "
                        "unreadable one)")
    p.set_defaults(run=run)


def problems(reader: Any) -> dict[str, list[str]]:
    """What is wrong with the recording or worth knowing: `damaged` episodes (and, for MCAP, a data section that
    fails its CRC: the whole file is read for it), `unfinished` ones, `notes`."""
    damaged = list(reader.damaged)
    check = getattr(reader, "check_data_crc", None)
    if check is not None and not damaged:
        wrong = check()
        if wrong:
            damaged.append(wrong)
    return {"damaged": damaged, "unfinished": list(reader.unfinished), "notes": list(reader.notes)}


def opened_episodes(reader: Any, found: dict[str, list[str]]) -> list[Any]:
    """The episodes' metadata, the first `OPENED_EPISODES` as opened (`EpisodeReader.open_episode`: with the notes
    and flags only their data gives, or a note saying why every command refuses the episode, unless a note of the
    file's says it already); a note in `found` when more are not opened."""
    from simreel.errors import FileProblemError

    episodes = list(reader.episodes)
    for k, listed in enumerate(episodes[:OPENED_EPISODES]):
        try:
            episodes[k] = reader.open_episode(listed.index).meta
        except FileProblemError as e:
            if e.problem not in found["notes"]:
                episodes[k] = dataclasses.replace(listed, notes=[*listed.notes, f"refused when read: {e.problem}"])
    if len(episodes) > OPENED_EPISODES:
        found["notes"].append(f"the first {OPENED_EPISODES} of {len(episodes)} episodes were opened for what only "
                              "their data shows (a first state off by one, an episode every command refuses); "
                              "`simreel replay` opens every one")
    return episodes


def summarize(reader: Any, found: dict[str, list[str]] | None = None,
              episodes: list[Any] | None = None) -> dict[str, Any]:
    """The JSON-able summary `inspect --json` prints (`episodes`: the episodes' metadata, by default as listed)."""
    m = reader.meta
    episodes = reader.episodes if episodes is None else episodes
    return {
        "path": str(reader.path),
        "kind": reader.kind,
        "meta": m.to_json(),
        "episodes": [e.to_json() for e in episodes],
        "total_steps": sum(e.length for e in episodes),
        "unseeded": dict(zip(("episodes", "with_generators"), unseeded_counts(episodes), strict=True)),
        **(found if found is not None else problems(reader)),
    }


def unseeded_counts(episodes: list[Any]) -> tuple[int, int]:
    """(episodes reset without a seed, a ManiSkill file's stale seed counted as none (`EpisodeMeta.seed_unchecked`),
    those of them whose random generators' states were captured at the reset: a replay sets them again and remakes
    the reset; `simreel.sim.generators`)."""
    unseeded = [e for e in episodes if e.seed is None or e.seed_unchecked]
    return len(unseeded), sum(bool(e.reset_generators) for e in unseeded)


def _unseeded_line(episodes: list[Any]) -> str:
    unseeded, captured = unseeded_counts(episodes)
    if not unseeded:
        return ""
    stale = sum(e.seed_unchecked for e in episodes)
    return (f"unseeded: {unseeded} episode(s) reset without a seed; {captured} with their random generators' states "
            f"(a replay remakes their reset), {unseeded - captured} without (a replay starts them from their "
            "recorded initial state: not exact" + (f"; {stale} with a seed the file gives that may be stale, kept where "
                                                   "it remakes that state" if stale else "") + ")")


def _hz(freq: float | None) -> str:
    return "?" if freq is None else f"{freq:g}"  # files written through the API may lack frequencies


def _reward_mode(meta: Any) -> str:
    """The reward mode the env used: the recorded one, else (a RecordEpisode file made without one) the task's
    default, which ManiSkill takes when none is given, said to be that, with whether the file holds rewards."""
    if meta.reward_mode is not None:
        return meta.reward_mode
    from simreel.errors import SimreelError
    from simreel.sim.make import reward_modes

    try:
        default = reward_modes(meta.env_id)[0]
    except (SimreelError, IndexError):  # a task not registered here: its default is not known
        default = "?"
    held = "not in the file" if "rewards" in meta.unknown else "recorded"
    return f"{default} (the task's default: the file names none; rewards {held})"


def _print_header(reader: Any) -> None:
    m = reader.meta
    print(f"{reader.path}  ({reader.kind})")
    if m.source:
        print("  source     " + ", ".join(f"{k} {v}" for k, v in m.source.items()))
    if m.provenance:
        from simreel.datasets.provenance import describe_provenance

        print(f"  made by    {describe_provenance(m.provenance)}")
    print(f"  env        {m.env_id}  obs={m.obs_mode} control={m.control_mode} reward={_reward_mode(m)}")
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
    if m.recording_id:
        print(f"  id         {m.recording_id}")
    if m.unknown:
        print(f"  unknown    not in the file: {', '.join(m.unknown)}")


def _print_episodes(eps: list[Any]) -> None:
    from simreel.datasets.provenance import describe_origin

    succ = sum(1 for e in eps if e.success)
    origins = [describe_origin(e.origin) for e in eps]
    width = max(map(len, origins), default=0)
    origin_head = f" {'origin':<{width}}" if width else ""
    print(f"\nepisodes: {len(eps)}, steps: {sum(e.length for e in eps)}, successful at the end: {succ}")
    if _unseeded_line(eps):
        print(_unseeded_line(eps))
    print(f"  {'index':>5} {'env':>4} {'seed':>11} {'steps':>6} {'success':>8}{origin_head}  reset")
    for e, origin in zip(eps, origins, strict=True):
        reset = "reconfigured" if e.reconfigured else ""
        if e.reset_options:
            reset += f" options={json.dumps(e.reset_options)}"
        shown = f" {origin:<{width}}" if width else ""
        print(f"  {e.index:>5} {e.env_idx:>4} {e.seed!s:>11} {e.length:>6} {e.success!s:>8}{shown}  {reset.strip()}")
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


def _print_text(reader: Any, found: dict[str, list[str]], episodes: list[Any]) -> None:
    _print_header(reader)
    _print_episodes(episodes)
    _print_layouts(reader.meta)
    _print_tools(reader)
    for note in found["notes"]:
        print(f"note: {note}")
    if found["unfinished"]:
        print(f"\nwarning: {len(found['unfinished'])} episode(s) were still running when the recording process stopped "
              f"and were not committed: {', '.join(found['unfinished'])}")
    if found["damaged"]:
        print(f"\nwarning: damaged, not readable: {'; '.join(found['damaged'])}")


def run(args: argparse.Namespace) -> int:
    from simreel.datasets.inputs import expand_inputs
    from simreel.formats import open_reader

    files = expand_inputs(args.paths)
    if len(files) == 1 and files[0][1]:
        with open_reader(args.paths[0]) as reader:
            found = problems(reader)
            episodes = opened_episodes(reader, found)
            if args.json:
                print(json.dumps(summarize(reader, found, episodes), indent=2))
            else:
                _print_text(reader, found, episodes)
        return 1 if found["damaged"] else 0
    return _inspect_many([path for path, _ in files], as_json=args.json)


def _inspect_many(paths: list[Any], *, as_json: bool) -> int:
    """One line per recording (or a JSON list of summaries), the totals; 2 when one could not be read, 1 when one
    is damaged."""
    from simreel.datasets.inputs import shown_path
    from simreel.errors import FileProblemError, SimreelError
    from simreel.formats import open_reader

    entries: list[dict[str, Any]] = []
    for path in paths:
        try:
            with open_reader(path) as reader:
                entries.append(summarize(reader))
        except SimreelError as e:
            entries.append({"path": str(path), "error": e.problem if isinstance(e, FileProblemError) else str(e)})
    if as_json:
        print(json.dumps(entries, indent=2))
    else:
        _print_table(entries, shown_path)
    if any("error" in e for e in entries):
        return 2
    return 1 if any(e["damaged"] for e in entries) else 0


def _print_table(entries: list[dict[str, Any]], shown: Any) -> None:
    width = max(len(shown(e["path"])) for e in entries)
    print(f"{'file':<{width}}  {'env id':<28} {'episodes':>8} {'steps':>8} {'success':>8}  format")
    for e in entries:
        name = shown(e["path"])
        if "error" in e:
            print(f"{name:<{width}}  unreadable: {e['error']}")
            continue
        eps = e["episodes"]
        success = sum(1 for m in eps if m["success"])
        damaged = f"  damaged: {'; '.join(e['damaged'])}" if e["damaged"] else ""
        print(f"{name:<{width}}  {e['meta']['env_id']:<28} {len(eps):>8} {e['total_steps']:>8} {success:>8}  {e['kind']}"
              + damaged)
    good = [e for e in entries if "error" not in e]
    print(f"{len(entries)} recordings ({len(entries) - len(good)} unreadable): "
          f"{sum(len(e['episodes']) for e in good)} episodes, {sum(e['total_steps'] for e in good)} steps")
