"""The Foxglove layout for an MCAP recording: its panels show the recording's own topics and /plots fields."""

from __future__ import annotations

import json

import pytest
from support.mcap_samples import synthetic_episode, synthetic_meta, write

from simreel.errors import RecordingFileError, UsageError
from simreel.formats.mcap import TOPICS
from simreel.formats.mcap.layout import write_foxglove_layout


@pytest.fixture
def recording(tmp_path):
    meta = synthetic_meta()
    return write(tmp_path / "s.mcap", meta, [synthetic_episode(meta, 0, 2)])


def _plots_schema(path) -> dict:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    channel = next(c for c in summary.channels.values() if c.topic == TOPICS["plots"])
    return json.loads(summary.schemas[channel.schema_id].data)


def test_the_layout_draws_the_scene_in_world_and_plots_fields_the_recording_has(recording, tmp_path):
    out = write_foxglove_layout(recording, tmp_path / "layout.json")
    layout = json.loads(out.read_text())
    panels = layout["configById"]
    assert set(panels) == {layout["layout"]["first"], layout["layout"]["second"]["first"],
                           layout["layout"]["second"]["second"]}
    three_d = panels["3D!simreel"]
    assert three_d["followTf"] == "world" and three_d["topics"][TOPICS["scene"]]["visible"]
    properties = _plots_schema(recording)["properties"]
    for path in panels["Plot!simreel"]["paths"]:
        topic, _, field = path["value"].partition(".")
        head, _, rest = field.partition(".")
        assert topic == TOPICS["plots"] and head in properties
        assert not rest or rest in properties[head]["properties"]
    assert {p["value"] for p in panels["Plot!simreel"]["paths"]} >= {"/plots.reward", "/plots.info.is_grasped"}
    assert panels["Log!simreel"]["topicToRender"] == TOPICS["log"]


def test_an_existing_layout_is_kept_and_a_wrong_input_named(recording, tmp_path):
    out = tmp_path / "layout.json"
    out.write_text("mine")
    with pytest.raises(UsageError, match="already exists"):
        write_foxglove_layout(recording, out)
    assert out.read_text() == "mine"
    write_foxglove_layout(recording, out, overwrite=True)
    assert "configById" in json.loads(out.read_text())
    with pytest.raises(UsageError, match=r"a Foxglove layout is a \.json file"):
        write_foxglove_layout(recording, tmp_path / "layout.txt")
    with pytest.raises(RecordingFileError):
        write_foxglove_layout(tmp_path / "missing.mcap", tmp_path / "other.json")
    assert not (tmp_path / "other.json").exists()
