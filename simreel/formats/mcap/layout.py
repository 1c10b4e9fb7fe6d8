"""A Foxglove layout for simreel's MCAP recordings: a 3D panel that draws `/scene` on the `/tf` frames (display frame
`world`), a plot of `/plots` (reward, success and the recording's info scalars) and the `/log` lines. Foxglove imports
it from its layout menu ("Import from file..."); the file it reads is JSON (`write_foxglove_layout`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from simreel.errors import UsageError
from simreel.formats.mcap.records import TOPICS, WORLD_FRAME
from simreel.io.targets import check_output
from simreel.model.meta import RecordingMeta

__all__ = ["foxglove_layout", "write_foxglove_layout"]

_THREE_D, _PLOT, _LOG = "3D!simreel", "Plot!simreel", "Log!simreel"
_PLOTTED_KINDS = ("b", "i", "u", "f")


def _plot_paths(meta: RecordingMeta) -> list[dict[str, Any]]:
    import numpy as np

    names = ["reward", "success"] + [f"info.{k}" for k, s in meta.info_layout.items()
                                     if not s.shape and np.dtype(s.dtype).kind in _PLOTTED_KINDS and k != "success"]
    return [{"value": f"{TOPICS['plots']}.{name}", "enabled": True, "timestampMethod": "receiveTime"} for name in names]


def foxglove_layout(meta: RecordingMeta) -> dict[str, Any]:
    """The layout (Foxglove's JSON: panels by id, their arrangement) for a recording with metadata `meta`."""
    three_d = {
        "followTf": WORLD_FRAME,
        "followMode": "follow-none",
        "scene": {"transforms": {"showLabel": False, "axisScale": 0.3}},
        "topics": {TOPICS["scene"]: {"visible": True}, TOPICS["robot_description"]: {"visible": False}},
        "layers": {"grid": {"layerId": "foxglove.Grid", "instanceId": "grid", "visible": True, "frameId": WORLD_FRAME,
                            "size": 4, "divisions": 20}},
        "cameraState": {"perspective": True, "distance": 2.5, "phi": 60, "thetaOffset": 45, "target": [0, 0, 0.2],
                        "targetOffset": [0, 0, 0], "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.01,
                        "far": 500},
    }
    return {
        "configById": {
            _THREE_D: three_d,
            _PLOT: {"title": f"{meta.env_id}: /plots", "paths": _plot_paths(meta), "showLegend": True},
            _LOG: {"topicToRender": TOPICS["log"]},
        },
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": {"speed": 1},
        "layout": {"first": _THREE_D, "second": {"first": _PLOT, "second": _LOG, "direction": "column",
                                                  "splitPercentage": 70},
                   "direction": "row", "splitPercentage": 65},
    }


def write_foxglove_layout(recording: str | Path, out: str | Path, *, overwrite: bool = False) -> Path:
    """Write the layout for the MCAP recording `recording` to `out` (JSON); `UsageError` for a recording that is no
    simreel MCAP file, or an `out` that exists (unless `overwrite`)."""
    from simreel.formats.mcap.reader import McapReader

    out = Path(out)
    if out.suffix != ".json":
        raise UsageError(f"{out}: a Foxglove layout is a .json file; name it e.g. {out.with_suffix('.json').name}")
    check_output(out, overwrite=overwrite)
    with McapReader(recording) as reader:
        meta = reader.meta
    partial = out.with_name(f".{out.name}.partial")  # the layout takes its name complete
    partial.write_text(json.dumps(foxglove_layout(meta), indent=2) + "\n")
    os.replace(partial, out)
    return out
