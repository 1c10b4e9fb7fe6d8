"""How one field of an episode is stored: `DatasetWriter` writes it through h5py's low-level API.

Every dataset with data is chunked, each chunk through the filters every h5py build reads without plugins:
shuffle + gzip (or lzf, or none) and then the Fletcher-32 checksum, so a corrupted chunk fails to read. An
episode's field normally fits one chunk (up to `CHUNK_BYTES`), which HDF5 1.10 indexes with no index
structure at all; longer ones are cut into chunks of that size. The low-level calls with property lists
built once cost about a third of h5py's `create_dataset`, which matters because a commit creates ~16 of them.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from simreel.errors import UsageError

__all__ = ["DatasetWriter", "COMPRESSIONS", "check_compression", "CHUNK_BYTES", "chunk_rows", "image_storage"]

COMPRESSIONS = ("gzip", "lzf", None)
CHUNK_BYTES = 1 << 20
_GZIP_LEVEL = 4
_COPY_CHUNKS = 16
"""Chunks copied at a time from a scratch file (a long episode never sits in memory whole)."""
_MAX_DCPLS = 256
"""Creation property lists kept (one per chunk shape); past this many the cache starts over."""
_MAX_PLANS = 4096
"""Dataset plans kept (one per field and episode length, `DatasetWriter._plan`); past this many they start over."""


_IMAGE_MIN_ELEMENTS = 1024
"""An observation whose row has at least 2 dims and this many elements is image-like (camera images, depth,
segmentation, point clouds) and stored by `image_storage`."""
_IMAGE_CHUNK_FRAMES = 32
_IMAGE_TILE = 32
_POINT_TILE = 1024


def image_storage(name: str, row_shape: tuple[int, ...], rows: int) -> dict[str, Any] | None:
    """How to store an image-like observation dataset (h5py ``create_dataset`` options), or None for any other.

    Chunks span 32 frames and tile the image (32 x 32 pixels, all channels; a point list: 1024 points), gzip
    level 6 (a compressor every h5py build reads; the Fletcher-32 checksum after it as on every dataset). Measured on re-rendered PickCube episodes (128 x 128 rgb, 61
    frames): 3.1 KB/frame against 5.4 KB for ManiSkill's RecordEpisode (gzip 5 in h5py's automatic chunks of 16
    frames x 32 x 32 x 2); one chunk per frame would be 31.8 KB/frame: a frame alone loses the redundancy between
    frames. Point clouds: 16.5 KB/frame against ManiSkill's 302 KB (it stores xyzw and segmentation raw).
    Reading one frame costs ~10 ms (ManiSkill's layout ~9 ms).
    """
    if not name.startswith("obs/") or len(row_shape) < 2 or math.prod(row_shape) < _IMAGE_MIN_ELEMENTS:
        return None
    tile = _IMAGE_TILE if len(row_shape) >= 3 else _POINT_TILE
    chunks = (max(1, min(rows, _IMAGE_CHUNK_FRAMES)), *(min(n, tile) for n in row_shape[:-1]), row_shape[-1])
    return {"chunks": chunks, "compression": "gzip", "compression_opts": 6}


def chunk_rows(row_shape: tuple[int, ...], itemsize: int, rows: int) -> int:
    """Rows per chunk: the whole field up to `CHUNK_BYTES`, else as many rows as fit in it (at least 1)."""
    row_bytes = max(1, math.prod(row_shape) * itemsize)
    return int(max(1, min(rows, CHUNK_BYTES // row_bytes)))


class _Plan(NamedTuple):
    """What creating and writing one field of one episode length takes, in h5py's low-level objects."""

    name: bytes
    file_type: Any
    space: Any
    dcpl: Any
    memory_type: Any


def check_compression(compression: Any) -> None:
    """`UsageError` for a compression that is none of `COMPRESSIONS`, naming them."""
    if compression not in COMPRESSIONS:
        raise UsageError(f"unknown HDF5 compression {compression!r}; use one of {', '.join(map(str, COMPRESSIONS))}")


class DatasetWriter:
    """Creates datasets in an open file with one compression; its property lists are built once and reused."""

    def __init__(self, compression: str | None) -> None:
        from h5py import h5d, h5g, h5p, h5s

        check_compression(compression)
        self.compression = compression
        self._lcpl = h5p.create(h5p.LINK_CREATE)
        self._lcpl.set_create_intermediate_group(True)
        self._gcpl = h5p.create(h5p.GROUP_CREATE)
        self._gcpl.set_obj_track_times(False)
        self._empty = h5p.create(h5p.DATASET_CREATE)
        self._empty.set_obj_track_times(False)
        self._chunked: dict[tuple[tuple[int, ...], int | None], Any] = {}
        self._plans: dict[tuple[str, tuple[int, ...], np.dtype], _Plan] = {}
        # bound once: an import statement in the per-dataset calls costs ~2 us each, ~80 us per commit
        self._new_dataset, self._new_group, self._whole = h5d.create, h5g.create, h5s.ALL

    def _dcpl(self, chunk: tuple[int, ...], image_level: int | None = None) -> Any:
        """The creation property list of a chunked, filtered dataset with this chunk shape (`image_level`: an
        image's gzip level, `image_storage`, instead of the writer's compression); built once per shape and kept
        (up to `_MAX_DCPLS`: a recording's shapes are its fields times its episode lengths)."""
        from h5py import h5p, h5z

        key = (chunk, image_level)
        dcpl = self._chunked.get(key)
        if dcpl is None:
            if len(self._chunked) >= _MAX_DCPLS:
                self._chunked.clear()
            dcpl = h5p.create(h5p.DATASET_CREATE)
            dcpl.set_obj_track_times(False)
            dcpl.set_chunk(chunk)
            if image_level is not None:
                dcpl.set_deflate(image_level)
            elif self.compression is not None:
                dcpl.set_shuffle()
                if self.compression == "gzip":
                    dcpl.set_deflate(_GZIP_LEVEL)
                else:
                    dcpl.set_filter(h5z.FILTER_LZF, h5z.FLAG_OPTIONAL)
            dcpl.set_fletcher32()
            self._chunked[key] = dcpl
        return dcpl

    def group(self, parent: Any, name: str) -> Any:
        """A new group `name` in `parent` (an h5py object id); returns its id."""
        return self._new_group(parent, name.encode(), gcpl=self._gcpl)

    def _plan(self, name: str, shape: tuple[int, ...], dtype: np.dtype) -> _Plan:
        """How dataset `name` of this shape and dtype is created and written; worked out once per field and
        episode length and kept (up to `_MAX_PLANS`), since every episode of a recording repeats the same few."""
        key = (name, shape, dtype)
        plan = self._plans.get(key)
        if plan is None:
            from h5py import h5s, h5t

            if len(self._plans) >= _MAX_PLANS:
                self._plans.clear()
            image = image_storage(name, shape[1:], shape[0]) if shape[0] else None
            if 0 in shape:
                dcpl = self._empty  # nothing to chunk, filter or check
            elif image is not None:
                dcpl = self._dcpl(image["chunks"], image["compression_opts"])
            else:
                dcpl = self._dcpl((chunk_rows(shape[1:], dtype.itemsize, shape[0]), *shape[1:]))
            # h5py's own write would build the same memory type for an array of `dtype`
            plan = self._plans[key] = _Plan(name.encode(), h5t.py_create(dtype, logical=True), h5s.create_simple(shape),
                                            dcpl, h5t.py_create(dtype))
        return plan

    def create(self, group: Any, name: str, shape: tuple[int, ...], dtype: np.dtype) -> Any:
        """An empty dataset `name` (a path below `group`, intermediate groups created) laid out for `shape`;
        returns its id, to be written and closed by the caller."""
        return self._create(group, self._plan(name, shape, dtype))

    def _create(self, group: Any, plan: _Plan) -> Any:
        return self._new_dataset(group, plan.name, plan.file_type, plan.space, dcpl=plan.dcpl, lcpl=self._lcpl)

    def write(self, group: Any, name: str, data: np.ndarray) -> None:
        """Create dataset `name` in `group` (an h5py object id) holding `data`."""
        data = np.ascontiguousarray(data)
        plan = self._plan(name, data.shape, data.dtype)
        ds = self._create(group, plan)
        try:
            if data.size:
                ds.write(self._whole, self._whole, data, mtype=plan.memory_type)
        finally:
            ds.close()

    def text_attribute(self, obj: Any, name: str, value: np.bytes_) -> None:
        """Attach attribute `name` holding `value` (`simreel.formats.hdf5.layout.encode_text`) to `obj` (an h5py
        object id): the fixed-length, null-padded ASCII string h5py's ``attrs[name] = value`` stores, written
        directly (h5py creates it under a temporary name and renames it: twice the time)."""
        from h5py import h5a, h5s, h5t

        text_type = h5t.C_S1.copy()
        text_type.set_size(max(1, len(value)))
        text_type.set_strpad(h5t.STR_NULLPAD)
        attr = h5a.create(obj, name.encode(), text_type, h5s.create(h5s.SCALAR))
        try:
            attr.write(np.asarray(value), mtype=text_type)
        finally:
            attr.close()

    def copy(self, group: Any, name: str, source: Any) -> None:
        """Create dataset `name` in `group` (an h5py object id) from the h5py dataset `source`, a few chunks at a
        time."""
        import h5py

        out = h5py.Dataset(self.create(group, name, source.shape, source.dtype))
        try:
            step = (out.chunks[0] if out.chunks else max(1, source.shape[0])) * _COPY_CHUNKS
            for start in range(0, source.shape[0], step):
                out[start : start + step] = source[start : start + step]
        finally:
            out.id.close()
