"""`simreel.model.state_tree`: nested state dicts ⇄ key paths, leaf layouts, and the exact error for malformed input."""

from __future__ import annotations

import numpy as np
import pytest

from simreel.errors import KeyPathError, MetadataError
from simreel.model.state_tree import (
    LeafSpec,
    describe_leaf,
    flatten,
    layout_differences,
    layout_of,
    unflatten,
)


def test_flatten_and_unflatten_are_inverse_and_keep_order():
    tree = {"actors": {"cube": np.zeros((1, 13)), "goal": np.ones((1, 13))}, "controller": {"arm": {"target": np.zeros(3)}},
            "goal_height": np.zeros(1)}
    flat = flatten(tree)
    assert list(flat) == ["actors/cube", "actors/goal", "controller/arm/target", "goal_height"]
    again = unflatten(flat)
    assert list(again) == list(tree) and list(again["actors"]) == ["cube", "goal"]
    assert all(np.array_equal(flatten(again)[k], v) for k, v in flat.items())


def test_flatten_accepts_tensors_without_copying_numpy():
    torch = pytest.importorskip("torch")
    a = np.arange(3.0)
    flat = flatten({"x": a, "t": torch.ones(2)})
    assert flat["x"] is a and flat["t"].dtype == np.float32


@pytest.mark.parametrize(
    ("tree", "message"),
    [
        ({"a/b": 1}, "state key 'a/b' contains '/'; key paths could not be split back"),
        ({"actors": {"": 1}}, "state key '' under 'actors/': keys must be non-empty strings"),
        ({3: 1}, "state key 3 under 'the root': keys must be non-empty strings"),
    ],
)
def test_flatten_refuses_keys_that_cannot_be_paths(tree, message):
    with pytest.raises(KeyPathError) as e:
        flatten(tree)
    assert str(e.value) == message


@pytest.mark.parametrize(
    ("flat", "message"),
    [
        ({"a": 1, "a/b": 2}, "key path 'a/b' goes below the leaf 'a'"),
        ({"a/b": 2, "a": 1}, "key path 'a' is both a leaf and a group of other paths"),
        ({"a//b": 1}, "key path 'a//b' has an empty part"),
        ({"a/": 1}, "key path 'a/' has an empty part"),
    ],
)
def test_unflatten_refuses_paths_that_are_no_tree(flat, message):
    with pytest.raises(KeyPathError) as e:
        unflatten(flat)
    assert str(e.value) == message


def test_layout_of_drops_the_batch_dimension_only_when_batched():
    flat = {"actors/cube": np.zeros((4, 13), np.float32), "goal": np.zeros((4,), np.float64)}
    assert layout_of(flat, batched=True) == {"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((), "float64")}
    assert layout_of(flat, batched=False)["actors/cube"] == LeafSpec((4, 13), "float32")


def test_leaf_specs_round_trip_through_json():
    spec = LeafSpec((2, 3), "int16")
    assert LeafSpec.from_json(spec.to_json()) == spec
    assert describe_leaf(spec) == "(2, 3) int16" and describe_leaf(None) == "absent"


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"shape": [2]}, "leaf spec {'shape': [2]}: expected {'shape': [...], 'dtype': '...'}"),
        ([2, "float32"], "leaf spec [2, 'float32']: expected {'shape': [...], 'dtype': '...'}"),
        ({"shape": "2", "dtype": "float32"}, "shape must be a list of sizes >= 0"),
        ({"shape": [-1], "dtype": "float32"}, "shape must be a list of sizes >= 0"),
        ({"shape": [2.5], "dtype": "float32"}, "shape must be a list of sizes >= 0"),
        ({"shape": [2], "dtype": "floaty"}, "'floaty' is not a numpy dtype"),
    ],
)
def test_malformed_leaf_specs_are_named(doc, message):
    with pytest.raises(MetadataError) as e:
        LeafSpec.from_json(doc)
    assert message in str(e.value)


def test_layout_differences_name_each_leaf():
    old = {"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((1,), "float32")}
    new = {"actors/cube": LeafSpec((13,), "float32"), "goal": LeafSpec((2,), "float32"), "extra": LeafSpec((), "int64")}
    assert layout_differences(old, new, new_label="replay") == [
        "extra: recorded absent, replay () int64",
        "goal: recorded (1,) float32, replay (2,) float32",
    ]
    assert layout_differences(old, old) == []
