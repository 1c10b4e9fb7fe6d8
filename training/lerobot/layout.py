"""The LeRobot dataset v3.0 layout (as lerobot 0.4's `lerobot.datasets.utils` defines it) and its metadata files:

    meta/info.json                              codebase_version "v3.0", fps, features, totals, path templates
    meta/stats.json                             each feature's min, max, mean, std, count and quantiles
    meta/tasks.parquet                          task text (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet    one row per episode: its index range, data file, tasks, stats
    data/chunk-000/file-000.parquet             the frames, many episodes a file
    videos/<key>/chunk-000/file-000.mp4         a camera's frames, many episodes a file (`videos`)

A feature of shape (1,) is a plain column, one of shape (n,) a fixed-size list column (LeRobot reads both through
Hugging Face `datasets` with the features info.json lists)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from simreel import __version__

__all__ = ["CODEBASE_VERSION", "CHUNKS_SIZE", "DATA_PATH", "EPISODES_PATH", "INFO_PATH", "STATS_PATH", "TASKS_PATH", "VIDEO_PATH",
           "QUANTILES", "FrameFeature", "info_document", "write_json", "write_tasks", "chunk_file", "arrow_column",
           "is_lerobot_dataset"]

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000
"""Files a chunk folder holds before the next one starts."""
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
"""The quantiles LeRobot keeps of each feature (``q01`` .. ``q99``)."""
DATA_FILE_MB = 100
"""A data file holds episodes until it reaches about this many MB (LeRobot's default)."""


class FrameFeature:
    """One column of the data files: its LeRobot name, dtype ("float32", "bool", "int64"), length (1: a plain
    column), and the names of its elements (None for a plain column)."""

    def __init__(self, key: str, dtype: str, length: int, names: Sequence[str] | None = None) -> None:
        self.key, self.dtype, self.length = key, dtype, length
        self.names = list(names) if names is not None else None

    def info(self) -> dict[str, Any]:
        """Its entry in info.json's ``features``."""
        return {"dtype": self.dtype, "shape": [self.length], "names": self.names}

    def arrow_type(self) -> pa.DataType:
        scalar = pa.from_numpy_dtype(np.dtype(self.dtype))
        return scalar if self.names is None else pa.list_(scalar, self.length)


def arrow_column(feature: FrameFeature, values: np.ndarray) -> pa.Array:
    """`values` ((frames,) or (frames, length)) as the column of `feature`, without a copy of their bytes."""
    values = np.ascontiguousarray(values, dtype=feature.dtype)
    if feature.names is None:
        return pa.array(values.reshape(-1), type=feature.arrow_type())
    flat = pa.array(values.reshape(-1), type=pa.from_numpy_dtype(values.dtype))
    return pa.FixedSizeListArray.from_arrays(flat, feature.length)


def chunk_file(number: int) -> dict[str, int]:
    """The chunk and file index of the `number`-th file of a kind (1000 files a chunk)."""
    return {"chunk_index": number // CHUNKS_SIZE, "file_index": number % CHUNKS_SIZE}


def info_document(*, fps: float, features: Sequence[FrameFeature], totals: Mapping[str, int], robot_type: str | None,
                  provenance: Mapping[str, Any]) -> dict[str, Any]:
    """meta/info.json: what LeRobot's `create_empty_dataset_info` writes, with the totals of the export, and
    ``simreel``: where the frames came from (the source files, the report whose verdicts chose the episodes)."""
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": robot_type,
        **totals,
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILE_MB,
        "video_files_size_in_mb": 200,
        "fps": int(fps) if float(fps).is_integer() else fps,
        "splits": {"train": f"0:{totals['total_episodes']}"},
        "data_path": DATA_PATH,
        "video_path": VIDEO_PATH if any(f.info()["dtype"] == "video" for f in features) else None,
        "features": {f.key: f.info() for f in features},
        "simreel": {"version": __version__, **provenance},
    }


def write_json(path: Path, document: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=4) + "\n")


def write_tasks(path: Path, tasks: Sequence[str]) -> None:
    """meta/tasks.parquet: the task texts as the pandas index (named ``task``) and their ``task_index``, as LeRobot's
    `write_tasks` (``DataFrame.to_parquet``) stores them, so `pandas.read_parquet` gives the same frame."""
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                            "metadata": {"encoding": "UTF-8"}}],
        "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
                     "metadata": None},
                    {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object",
                     "metadata": None}],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = pa.table({"task_index": pa.array(range(len(tasks)), type=pa.int64()),
                      "task": pa.array(list(tasks), type=pa.string())})
    table = table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def is_lerobot_dataset(folder: Path) -> bool:
    """Whether `folder` holds a LeRobot dataset (meta/info.json with a codebase version): what ``--overwrite`` may
    replace."""
    try:
        return "codebase_version" in json.loads((folder / INFO_PATH).read_text())
    except (OSError, ValueError, TypeError):
        return False
