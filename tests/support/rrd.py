"""Read a Rerun .rrd back with rerun-sdk's own reader (`rerun.chunk.RrdReader`)."""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path
from typing import Any

__all__ = ["RrdContents", "read_rrd"]


@dataclasses.dataclass
class RrdContents:
    """What an .rrd holds: `data[entity][column]` → list of (step or None for static, value)."""

    data: dict[str, dict[str, list[tuple[int | None, Any]]]]
    blueprint_views: list[str]
    blueprint_entities: list[str]
    recording_ids: list[str]

    def at(self, entity: str, column: str, step: int | None) -> Any:
        for s, value in self.data[entity][column]:
            if s == step:
                return value
        raise KeyError(f"{entity} {column} has no row at step {step}")

    def steps(self, entity: str, column: str) -> list[int]:
        return [s for s, _ in self.data[entity][column] if s is not None]


def _columns(batch: Any) -> dict[str, list]:
    """A record batch as {column: python list}; time columns as int64 (nanoseconds for log_time/sim_time)."""
    import pyarrow as pa

    out = {}
    for name, column in zip(batch.schema.names, batch.columns, strict=True):
        if pa.types.is_temporal(column.type):
            column = column.cast(pa.int64())
        out[name] = column.to_pylist()
    return out


def read_rrd(path: Path) -> RrdContents:
    import rerun as rr

    reader = rr.chunk.RrdReader(path)
    data: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in reader.store().stream().to_chunks():
        if chunk.entity_path.startswith("/__properties"):
            continue
        rows = _columns(chunk.to_record_batch())
        steps = rows.get("step", [None] * chunk.num_rows)
        for column, values in rows.items():
            if column in ("step", "sim_time") or column.startswith("rerun."):
                continue
            data[chunk.entity_path][column].extend(zip(steps, values, strict=True))
    views, entities = [], []
    for entry in reader.blueprints():
        for chunk in reader.store(store=entry).stream().to_chunks():
            entities.append(chunk.entity_path)
            rows = _columns(chunk.to_record_batch())
            views += [v[0] if isinstance(v, list) else v for v in rows.get("ViewBlueprint:class_identifier", [])]
    return RrdContents({k: dict(v) for k, v in data.items()}, views, entities,
                       [e.recording_id for e in reader.recordings()])
