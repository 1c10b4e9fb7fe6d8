"""Nested state dicts ⇄ flat `"a/b/c"` key paths, and the layout (shape, dtype) of each leaf.

ManiSkill's `get_state_dict()` is nested (`actors/cube`, `articulations/panda`, `controller/arm/...`,
custom task keys). simreel keeps that nesting as key paths everywhere, so every format and report can
name the exact leaf ("env_states/actors/cube"), and can rebuild the nested dict for `set_state_dict`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from simreel.errors import KeyPathError, MetadataError

__all__ = ["LeafSpec", "flatten", "unflatten", "to_numpy", "layout_of", "layout_differences", "describe_leaf", "SEP"]

SEP = "/"


@dataclass(frozen=True)
class LeafSpec:
    """Shape (per env, without the batch dimension) and numpy dtype name of one state leaf."""

    shape: tuple[int, ...]
    dtype: str

    def to_json(self) -> dict[str, Any]:
        return {"shape": list(self.shape), "dtype": self.dtype}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> LeafSpec:
        """The spec of `d` = ``{"shape": [...], "dtype": "..."}``; `MetadataError` naming what is wrong."""
        if not isinstance(d, Mapping) or "shape" not in d or "dtype" not in d:
            raise MetadataError(f"leaf spec {d!r}: expected {{'shape': [...], 'dtype': '...'}}")
        shape, dtype = d["shape"], d["dtype"]
        if not isinstance(shape, list) or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 0
                                                  for x in shape):
            raise MetadataError(f"leaf spec {d!r}: shape must be a list of sizes >= 0")
        try:
            np.dtype(dtype)
        except TypeError:
            raise MetadataError(f"leaf spec {d!r}: {dtype!r} is not a numpy dtype") from None
        return cls(tuple(shape), str(dtype))


def to_numpy(x: Any) -> np.ndarray:
    """A numpy copy-free view of a numpy array, torch tensor (any device) or scalar."""
    if isinstance(x, np.ndarray):
        return x
    if hasattr(x, "detach"):  # torch.Tensor, without importing torch
        try:
            return x.numpy()  # a CPU tensor outside autograd: half the cost of the line below
        except (TypeError, RuntimeError):
            return x.detach().cpu().numpy()
    return np.asarray(x)


def _walk(tree: Mapping[str, Any], prefix: str) -> Iterator[tuple[str, Any]]:
    for key, value in tree.items():
        if not isinstance(key, str) or not key:
            raise KeyPathError(f"state key {key!r} under {prefix or 'the root'!r}: keys must be non-empty strings")
        if SEP in key:
            raise KeyPathError(f"state key {key!r} contains {SEP!r}; key paths could not be split back")
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            yield from _walk(value, path + SEP)
        else:
            yield path, value


def flatten(tree: Mapping[str, Any], *, prefix: str = "") -> dict[str, np.ndarray]:
    """Flatten a nested dict of arrays/tensors into `{key_path: np.ndarray}` in insertion order."""
    return {path: to_numpy(value) for path, value in _walk(tree, prefix)}


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Inverse of `flatten`: `{"a/b": x}` → `{"a": {"b": x}}`.

    Raises `KeyPathError` for a path with an empty part (``a//b``) and for a path that is both a leaf and a
    group of other paths (``a`` and ``a/b``)."""
    tree: dict[str, Any] = {}
    for path, value in flat.items():
        parts = path.split(SEP)
        if not all(parts):
            raise KeyPathError(f"key path {path!r} has an empty part")
        node = tree
        for k, part in enumerate(parts[:-1]):
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise KeyPathError(f"key path {path!r} goes below the leaf {SEP.join(parts[: k + 1])!r}")
        if isinstance(node.get(parts[-1]), dict):
            raise KeyPathError(f"key path {path!r} is both a leaf and a group of other paths")
        node[parts[-1]] = value
    return tree


def layout_of(flat: Mapping[str, np.ndarray], *, batched: bool) -> dict[str, LeafSpec]:
    """Per-env layout of flat leaves; `batched` drops the leading num_envs dimension."""
    return {
        path: LeafSpec(tuple(a.shape[1:] if batched else a.shape), a.dtype.name) for path, a in flat.items()
    }


def describe_leaf(spec: LeafSpec | None) -> str:
    """``"(13,) float32"``, or ``"absent"`` for a leaf one layout does not have."""
    return "absent" if spec is None else f"{tuple(spec.shape)} {spec.dtype}"


def layout_differences(
    old: Mapping[str, LeafSpec], new: Mapping[str, LeafSpec], *, old_label: str = "recorded", new_label: str = "now"
) -> list[str]:
    """One line per leaf whose spec differs, in key order: ``"actors/cube: recorded (13,) float32, now absent"``."""
    return [
        f"{k}: {old_label} {describe_leaf(old.get(k))}, {new_label} {describe_leaf(new.get(k))}"
        for k in sorted(set(old) | set(new))
        if old.get(k) != new.get(k)
    ]
