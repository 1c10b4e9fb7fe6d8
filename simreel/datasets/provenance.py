"""What made a recording from others, in words (`describe_provenance`, `describe_origin`) and the tolerances it was
judged with (`provenance_tolerances`), for `simreel inspect` and the viewers."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from simreel.model.components import Tolerances
from simreel.model.lineage import EpisodeOrigin

__all__ = ["describe_provenance", "describe_origin", "provenance_tolerances"]


def describe_provenance(provenance: Mapping[str, Any]) -> str:
    """One line saying what made a recording from others (`RecordingMeta.provenance`), for `simreel inspect`."""
    if provenance.get("operation") == "convert":
        return _describe_conversion(provenance)
    if provenance.get("operation") == "replay":
        return _describe_replay(provenance)
    inputs = provenance.get("inputs") or []
    names = ", ".join(f"{Path(i.get('path', '?')).name} ({i.get('episodes', '?')} episode(s))" for i in inputs[:5])
    names += f", ... ({len(inputs)} files)" if len(inputs) > 5 else ""
    line = f"{provenance.get('operation', '?')} of {names or 'nothing'}"
    criteria = provenance.get("criteria")
    if criteria:
        line += "; criteria " + ", ".join(f"{k} {json.dumps(v)}" for k, v in criteria.items())
    if provenance.get("part"):
        line += f"; the episodes {'kept' if provenance['part'] == 'kept' else 'not kept'}"
    return line


def _describe_conversion(provenance: Mapping[str, Any]) -> str:
    """``convert of /data/demos.h5 (episodes 0, 1): control_mode pd_joint_pos -> pd_ee_delta_pose; kept: verified``."""
    conversion = provenance.get("conversion") or {}
    changed = [f"{k} {v[0]} -> {v[1]}" for k, v in conversion.items() if isinstance(v, list) and len(v) == 2]
    episodes = ", ".join(str(i) for i in provenance.get("source_episodes", []))
    keep = (provenance.get("filters") or {}).get("keep")
    return (f"convert of {provenance.get('source')} (episodes {episodes}): {'; '.join(changed)}"
            + (f"; kept: {', '.join(keep)}" if keep else ""))


def _describe_replay(provenance: Mapping[str, Any]) -> str:
    """``replay of /data/demos.h5 (simreel replay --mode step; pos 0.1 instead of its defaults), each episode's
    verdict kept; the input: convert of ...``."""
    run, judged = _replay_command(provenance), provenance_tolerances(provenance)
    changed = judged[0].overrides(judged[2]) if judged else ""
    if changed:
        run += f"; {changed} instead of its defaults"
    line = f"replay of {provenance.get('source')} ({run}), each episode's verdict kept"
    of = provenance.get("input")
    return line + (f"; the input: {describe_provenance(of)}" if of else "")


def _replay_command(made: Mapping[str, Any]) -> str:
    """``simreel replay --mode actions --resync 5``: the replay of provenance `made`, its options that chose its
    tolerances' defaults."""
    resync = made.get("resync")
    return f"simreel replay --mode {made.get('mode')}" + (f" --resync {resync}" if resync else "")


def provenance_tolerances(made: Mapping[str, Any]) -> tuple[Tolerances, str, str] | None:
    """The tolerances the replay (``simreel replay -o``) or conversion of provenance `made` judged its file with, the
    command that did (``simreel replay --mode step``), and the mode whose defaults it started from; None where it
    holds none this simreel can read (a control-mode conversion's tracking tolerances, another operation)."""
    stored = made.get("tolerances")
    if made.get("operation") == "replay":
        base, run = ("resync" if made.get("resync") else made.get("mode")), _replay_command(made)
    elif made.get("operation") == "convert":
        base, run = "states", "simreel convert"
    else:
        return None
    try:
        return Tolerances.for_mode(base, groups=stored), run, base
    except (TypeError, ValueError):  # no tolerances, or not these groups
        return None


def describe_origin(origin: EpisodeOrigin | None) -> str:
    """``file.h5#3``: where an episode was copied from (`EpisodeMeta.origin`); empty for a recorded one."""
    return f"{Path(origin.file).name}#{origin.index}" if origin is not None else ""
