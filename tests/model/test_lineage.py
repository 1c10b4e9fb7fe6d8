"""The typed records of an episode's lineage (`simreel.model.lineage`): provenance and verification read the JSON that
simreel's files hold (as written before they were records, by main at 5d79022) and write it back unchanged, refuse
malformed JSON with one `MetadataError` naming the field, and keep keys this version does not know."""

from __future__ import annotations

import dataclasses

import pytest

from simreel.errors import MetadataError
from simreel.model.lineage import EpisodeProvenance, EpisodeVerification, ScenePlace
from simreel.model.meta import EpisodeMeta

SCENE = {"file": "/data/conv.h5", "position": 1, "recording": "9b34814aeebe46ad81b8051e457a6f03", "start": 0}
CONVERTED = {"checked": ["commanded pose", "end-effector pose", "object poses", "success"], "clipped_steps": 0,
             "first_exceeded": None, "max_error": {"command/panda_hand_tcp[p]": 5.960464477539063e-08, "success": 0.0,
                                                   "ee/panda_hand_tcp[q]": "nan"},
             "scene": SCENE, "source_episode": 1, "verdict": "within_tolerance"}
"""An episode's provenance as `simreel convert --control-mode` wrote it (main at 5d79022; a NaN error as its text)."""
RE_RENDERED = {"source_episode": 0, "verdict": "exact", "checked": [], "max_error": {},
               "first_exceeded": {"step": 3, "key": "obs/agent/qpos", "error": 0.5, "tolerance": 0.001}}
REPLAYED = {"scene": SCENE}
"""`simreel replay -o` of a recorded episode: where it ran, nothing else."""
VERIFIED = {"explanation": None, "first_divergence": None, "scene_differences": [], "verdict": "exact"}


@pytest.mark.parametrize("provenance", [CONVERTED, RE_RENDERED, REPLAYED, {}], ids=["converted", "re-rendered",
                                                                                     "replayed", "recorded"])
@pytest.mark.parametrize("verification", [VERIFIED, {}], ids=["verified", "none"])
def test_the_json_simreel_wrote_reads_as_records_and_writes_back_unchanged(provenance, verification):
    d = {"index": 1, "length": 8, "provenance": provenance, "verification": verification}
    meta = EpisodeMeta.from_json(d)
    assert meta.to_json()["provenance"] == provenance and meta.to_json()["verification"] == verification
    assert (meta.provenance is None) == (not provenance) and (meta.verification is None) == (not verification)
    if provenance:
        assert meta.provenance.scene == (ScenePlace.from_json(SCENE) if "scene" in provenance else None)
        assert meta.provenance.verdict == provenance.get("verdict")
    if verification:
        assert meta.verification.verdict == "exact" and meta.verification.scene_differences == []


def test_the_records_are_typed():
    p = EpisodeProvenance.from_json(CONVERTED)
    assert (p.source_episode, p.verdict, p.checked[0], p.clipped_steps) == (1, "within_tolerance", "commanded pose", 0)
    assert EpisodeMeta(2, provenance=CONVERTED, verification=VERIFIED) == \
        EpisodeMeta(2, provenance=p, verification=EpisodeVerification("exact", scene_differences=[]))


def test_a_provenance_whose_scene_is_taken_away_is_none_as_its_file_reads():
    replayed = EpisodeMeta(1, provenance=REPLAYED)
    emptied = dataclasses.replace(replayed, provenance=dataclasses.replace(replayed.provenance, scene=None))
    assert replayed.provenance is not None and emptied.provenance is None
    assert emptied == EpisodeMeta.from_json(emptied.to_json())


def test_keys_this_version_does_not_know_are_kept():
    d = {"index": 0, "provenance": {**RE_RENDERED, "tool": "v9"}, "verification": {**VERIFIED, "history": [1]}}
    assert {k: EpisodeMeta.from_json(d).to_json()[k] for k in ("provenance", "verification")} == \
        {"provenance": d["provenance"], "verification": d["verification"]}


@pytest.mark.parametrize(("field", "value", "start"), [
    ("provenance", {"source_episode": -1}, "episode metadata: provenance is {\"source_episode\": -1}, expected"),
    ("provenance", {"verdict": 3}, "episode metadata: provenance is {\"verdict\": 3}, expected"),
    ("provenance", {"checked": "poses"}, "episode metadata: provenance is {\"checked\": \"poses\"}, expected"),
    ("provenance", {"scene": {"file": 1}}, "episode metadata: provenance.scene is {\"file\": 1}, expected"),
    ("provenance", ["exact"], "episode metadata: provenance is ['exact'], expected"),
    ("verification", {"first_divergence": None}, "episode metadata: verification is {\"first_divergence\": null}, "
                                                 "expected"),
    ("verification", {"verdict": "exact", "scene_differences": {}}, "episode metadata: verification is"),
])
def test_malformed_json_is_one_metadata_error_naming_the_field(field, value, start):
    with pytest.raises(MetadataError) as refused:
        EpisodeMeta.from_json({"index": 0, field: value})
    assert str(refused.value).startswith(start)
