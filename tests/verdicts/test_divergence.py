"""The data part of a divergence explanation (simreel.verdicts.divergence): events with their steps and forces, error growth,
onset, and the explanation's JSON. Synthetic episodes with known answers; the real causes are in tests/replay."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.meta import ContactChannel, EpisodeMeta
from simreel.verdicts.compare import compare_episode
from simreel.verdicts.divergence import (
    Cause,
    EpisodeEvent,
    Explanation,
    describe_divergence,
    divergence_onset,
    episode_events,
    error_growth,
)

T = 12
CHANNELS = [ContactChannel("net", ("cube",)), ContactChannel("pair", ("finger", "cube"))]


def _episode() -> Episode:
    """A cube lying still (a resting contact from the first step on), a finger touching it at steps 4-8 with 3 N,
    grasped at steps 5-8, success at step 7, a controller target that jumps at step 9."""
    forces = np.zeros((T, 2, 3), np.float32)
    forces[:, 0, 2] = 0.6  # resting on the table all along: no event
    forces[4:9, 1, 0] = 3.0
    grasped = np.zeros(T, bool)
    grasped[5:9] = True
    success = np.zeros(T, bool)
    success[7:] = True
    target = np.cumsum(np.full((T + 1, 3), 0.001, np.float32), axis=0)
    target[10:] += 0.5  # the state after step 9 onwards
    cube = np.zeros((T + 1, 13), np.float32)
    cube[:, 3] = 1.0
    return Episode(
        meta=EpisodeMeta(index=0, seed=1, length=T),
        actions=np.zeros((T, 2), np.float32),
        rewards=np.zeros(T, np.float32),
        terminated=np.zeros(T, bool), truncated=np.zeros(T, bool), success=success, fail=np.zeros(T, bool),
        env_states={"actors/cube": cube, "controller/arm/target": target},
        info={"is_grasped": grasped},
        contact_forces=forces,
    )


def test_events_name_steps_pairs_and_forces():
    events = episode_events(_episode(), CHANNELS)
    got = [(e.step, e.kind, e.subject) for e in events]
    assert got == [
        (4, "contact_begins", "finger:cube"),
        (5, "grasp_begins", "info/is_grasped"),
        (7, "success", ""),
        (9, "contact_ends", "finger:cube"),
        (9, "controller_jump", "controller/arm/target"),
        (9, "grasp_ends", "info/is_grasped"),
    ]
    begins = events[0]
    assert begins.value == pytest.approx(3.0) and begins.describe() == "step 4: contact finger:cube begins (3 N)"
    assert events[3].describe() == "step 9: contact finger:cube ends (was 3 N)"
    assert events[4].value == pytest.approx(0.501, abs=1e-6)
    assert [e.step for e in episode_events(_episode(), CHANNELS, first=5, last=7)] == [5, 7]


def _diverged(offsets: np.ndarray, start: int) -> tuple[Episode, Episode]:
    """The episode and a replay whose cube x is off by offsets[k] at state row start + k."""
    recorded = _episode()
    cube = recorded.env_states["actors/cube"].copy()
    cube[start : start + len(offsets), 0] += offsets
    replayed = dataclasses.replace(recorded, env_states={**recorded.env_states, "actors/cube": cube})
    return recorded, replayed


def test_growth_tells_a_jump_with_constant_offset_from_growth():
    recorded, replayed = _diverged(np.full(5, 0.02), 6)  # rows 6..10: steps 5..9
    cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"))
    g = error_growth(cmp, "env_states/actors/cube[p]", 5, (2, 9))
    assert (g.step, g.trend, g.span) == (5, "constant offset", 3)
    assert g.describe() == "env_states/actors/cube[p]: 0.02 at step 5 (tolerance 1e-05), constant offset (×1 after 3 steps)"
    assert g.steps == list(range(2, 10)) and g.errors[3] == pytest.approx(0.02)

    recorded, replayed = _diverged(np.array([2e-8, 4e-8, 1e-7, 2e-5, 2e-4, 2e-3, 2e-2]), 3)  # steps 2..8
    cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"))
    d = cmp.first_divergence
    assert (d.step, d.key) == (5, "env_states/actors/cube[p]")
    g = error_growth(cmp, d.key, d.step, (0, 9))
    assert g.trend == "grew" and g.factor == pytest.approx(1000, rel=1e-3)
    assert g.describe().endswith("grew 1e+03× in 3 steps")


def test_growth_of_an_error_that_is_not_a_number_says_so_without_warnings():
    """NaN in the data (a replay of a damaged recording): no ratio of errors is printed, and numpy warns nothing."""
    recorded, replayed = _diverged(np.array([0.5, np.nan, np.nan, np.inf]), 6)
    cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = error_growth(cmp, "env_states/actors/cube[p]", 5, (2, 9))
    assert g.factor is None and g.describe() == (
        "env_states/actors/cube[p]: 0.5 at step 5 (tolerance 1e-05), no trend: NaN or infinity in the errors (the "
        "recording or the replay holds such values)")
    for offsets in ([np.nan, np.nan], [1e-7, np.inf]):  # NaN from the first difference on; a small one, then NaN
        recorded, replayed = _diverged(np.array(offsets), 6)
        cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"))
        onset = divergence_onset(cmp, cmp.first_divergence.step)
        assert onset.describe().endswith("; no ratio to the divergence: NaN or infinity in the errors there")


def test_onset_and_events_of_an_amplified_difference():
    recorded, replayed = _diverged(np.array([2e-8, 4e-8, 1e-7, 2e-5, 2e-4]), 3)
    cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"), channels=CHANNELS)
    explanation = describe_divergence(recorded, cmp, CHANNELS)
    onset = explanation.onset
    assert (onset.step, onset.key, onset.float_noise) == (2, "env_states/actors/cube[p]", True)
    assert onset.error == pytest.approx(2e-8) and onset.growth == pytest.approx(1000, rel=1e-3)
    assert [(e.step, e.kind) for e in explanation.events][:2] == [(4, "contact_begins"), (5, "grasp_begins")]
    assert explanation.cause is None  # data only: the replay room classifies


def test_explanation_round_trips_through_json():
    recorded, replayed = _diverged(np.array([2e-8, 4e-8, 1e-7, 2e-5, 2e-4]), 3)
    cmp = compare_episode(recorded, replayed, Tolerances.for_mode("actions"), channels=CHANNELS)
    explanation = describe_divergence(recorded, cmp, CHANNELS)
    explanation.cause = Cause("amplification", "grew", step=5, key="env_states/actors/cube[p]", evidence=["a", "b"])
    explanation.checked.append("one-step errors")
    doc = json.loads(json.dumps(explanation.to_json()))
    again = Explanation.from_json(doc)
    assert again.to_json() == explanation.to_json()
    assert doc["cause"] == {"kind": "amplification", "summary": "grew", "step": 5, "key": "env_states/actors/cube[p]",
                            "evidence": ["a", "b"]}
    assert doc["events"][0] == {"step": 4, "kind": "contact_begins", "subject": "finger:cube", "value": 3.0,
                                "text": "step 4: contact finger:cube begins (3 N)"}
    assert EpisodeEvent.from_json(doc["events"][0]) == explanation.events[0]
    lines = again.lines()
    assert lines[0] == "why: grew" and lines[1:3] == ["  a", "  b"]
    assert any(line.startswith("events: step 4: contact finger:cube begins (3 N)") for line in lines)


def test_nothing_to_explain_without_a_divergence():
    recorded = _episode()
    assert describe_divergence(recorded, compare_episode(recorded, recorded, Tolerances.for_mode("actions"))) is None
