"""simreel's MCAP files read by the TypeScript reader Foxglove opens files with (`@mcap/core`, installed by
`make test` into tools/mcap_ts where npm exists): every message streamed with its CRCs checked, and every message
through the indexed reader, which Foxglove uses for a seekable file."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from support.mcap_samples import long_sample

from simreel.cli.main import main
from simreel.formats import open_reader

TOOL = Path(__file__).resolve().parents[2] / "tools" / "mcap_ts"

pytestmark = pytest.mark.skipif(
    shutil.which("node") is None or not (TOOL / "node_modules" / "@mcap" / "core").is_dir(),
    reason="needs node and tools/mcap_ts/node_modules (`make test` installs them where npm exists)")


def _read_with_typescript(path: Path) -> dict:
    done = subprocess.run(["node", str(TOOL / "read.mjs"), str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _expected_counts(path: Path, scenes: int = 0) -> dict[str, int]:
    """Messages per topic simreel wrote: a reset row, and a log line as each episode begins and is committed, a
    transform per row, a plot per step, a scene update and a robot description per scene; and the blocks of exact
    step data as Python's mcap reader counts them."""
    from mcap.reader import make_reader

    with open_reader(path) as r:
        lengths = [m.length for m in r.episodes]
    with path.open("rb") as f:
        blocks = sum(1 for _ in make_reader(f).iter_messages(topics=["/simreel/steps"]))
    drawn = {"/scene": scenes, "/robot_description": scenes} if scenes else {}
    return {"/simreel/reset": len(lengths), "/simreel/steps": blocks, "/tf": sum(lengths) + len(lengths),
            "/plots": sum(lengths), "/log": 2 * len(lengths), **drawn}


def test_a_recording_reads_whole_in_foxglove_s_reader(tmp_path):
    """Regression: the files had chunk indexes without message indexes, which @mcap/core's indexed reader refuses
    ("a chunk index without message indexes"): Foxglove could not play any simreel MCAP file."""
    path = tmp_path / "run.mcap"
    assert main(["record", "PickCube-v1", "-o", str(path), "-n", "2", "--max-steps", "6", "--seed", "0",
                 "--render-backend", "none", "-q"]) == 0
    read = _read_with_typescript(path)
    assert "error" not in read["streamed"] and "error" not in read["indexed"], read
    expected = _expected_counts(path, scenes=1)
    assert read["streamed"]["counts"] == expected and read["indexed"]["counts"] == expected
    assert read["indexed"]["statistics"] == sum(expected.values())
    tf = read["streamed"]["first"]["/tf"]["transforms"]
    assert {t["parent_frame_id"] for t in tf} == {"world"} and "cube" in {t["child_frame_id"] for t in tf}
    assert read["streamed"]["first"]["/plots"]["step"] == 0


def test_the_scene_transforms_and_robot_description_decode_with_foxgloves_own_schemas(tmp_path):
    """/scene and /tf decode with the definitions of `@foxglove/schemas` (what Foxglove's panels are written against)
    as with the schemas the file carries, and /robot_description with Foxglove's ROS 2 message parser and CDR reader:
    the entities sit on /tf's frames and the description is the URDF of the same bodies."""
    import xml.etree.ElementTree as ET

    path = tmp_path / "run.mcap"
    assert main(["record", "PickCube-v1", "-o", str(path), "-n", "1", "--max-steps", "3", "--seed", "0",
                 "--render-backend", "none", "-q"]) == 0
    streamed = _read_with_typescript(path)["streamed"]
    assert "error" not in streamed, streamed
    own, carried = streamed["foxglove"], streamed["first"]
    assert own["/scene"] == carried["/scene"] and own["/tf"] == carried["/tf"] and own["/log"] == carried["/log"]
    frames = {t["child_frame_id"] for t in own["/tf"]["transforms"]}
    entities = own["/scene"]["entities"]
    assert {e["frame_id"] for e in entities} <= frames and all(e["frame_locked"] for e in entities)
    cube = next(e for e in entities if e["id"] == "cube")["cubes"][0]
    assert [cube["size"][k] for k in "xyz"] == pytest.approx([0.04] * 3)
    links = {link.get("name") for link in ET.fromstring(carried["/robot_description"]["data"]).iter("link")}
    assert links == {"world"} | {e["id"] for e in entities if e["frame_id"] != "world"}


def test_a_long_episode_over_many_chunks_reads_through_the_index(tmp_path):
    path, _ = long_sample(tmp_path / "long.mcap")
    read = _read_with_typescript(path)
    assert "error" not in read["indexed"], read
    assert read["indexed"]["counts"] == read["streamed"]["counts"] == _expected_counts(path)


def test_plots_of_a_non_finite_reward_match_their_json_schema(tmp_path):
    """/plots writes NaN and infinities as null (JSON has no such numbers): its schema says so."""
    jsonschema = pytest.importorskip("jsonschema")
    from mcap.reader import make_reader

    src, _ = long_sample(tmp_path / "long.h5")
    with open_reader(src) as r:
        assert np.issubdtype(r.read_episode(0).rewards.dtype, np.floating)
    path = tmp_path / "nan.mcap"
    _write_with_reward(src, path, np.nan)
    with path.open("rb") as f:
        for schema, _, message in make_reader(f).iter_messages(topics=["/plots"]):
            row = json.loads(message.data)
            jsonschema.validate(row, json.loads(schema.data))
    assert row["reward"] is None


def _write_with_reward(src: Path, dst: Path, reward: float) -> None:
    """`src`'s first episode written to `dst` with every reward set to `reward`."""
    import dataclasses

    from simreel.formats import open_writer

    with open_reader(src) as r:
        episode = r.read_episode(0)
        meta = r.meta
    episode = dataclasses.replace(episode, rewards=np.full_like(episode.rewards, reward))
    with open_writer(dst, meta) as w:
        w.write_episode(episode)
