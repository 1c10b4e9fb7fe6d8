"""The Rerun session of a diverged replay shows the explanation on the `events` timeline, at the steps its events
happened, next to the error curves; read back with rerun's own reader."""

from __future__ import annotations

import pytest
from support.unseeded import record_unseeded

from simreel.replay import verify_recording
from simreel.viewers import build_session


@pytest.fixture(scope="module")
def diverged(tmp_path_factory):
    """A LiftCube replay from a restored initial state (amplification through the grasp), written with -o."""
    folder = tmp_path_factory.mktemp("explained")
    path = record_unseeded("SimreelLiftCube-v1", folder / "lift.h5")
    replayed = folder / "replayed.h5"
    report = verify_recording(path, output=str(replayed))
    return path, replayed, report.episodes[0]


def test_the_explanation_is_on_the_timeline_next_to_the_error_curves(diverged, rrd_reader, tmp_path):
    path, replayed, episode = diverged
    explanation = episode.explanation
    d, cause = explanation.divergence, explanation.cause
    assert cause.kind == "amplification"
    out = tmp_path / "cmp.rrd"
    with build_session(path, compare=replayed, geometry="collision") as session:
        session.save(out)
    assert session.explanation.cause.to_json() == cause.to_json()  # the cause simreel replay -o stored
    rrd = rrd_reader(out)
    events = [(step, text[0]) for step, text in rrd.data["/events"]["TextLog:text"]]
    assert (d.step, f"why: {cause.summary}") in events
    touch = next(e for e in explanation.events if e.kind == "contact_begins" and "finger" in e.subject)
    assert (touch.step, touch.describe().split(": ", 1)[1]) in events  # "contact ... begins (30.7 N)" at its step
    assert touch.describe().endswith(" N)")
    onset = explanation.onset
    assert (onset.step, f"onset: {onset.describe()}") in events
    growth = explanation.growth[0]
    assert (growth.step, f"error: {growth.describe()}") in events
    key = d.key.replace("[", r"\[").replace("]", r"\]")
    curve = dict(rrd.data[f"/plots/error/{key}"]["Scalars:scalars"])
    assert curve[d.step][0] == pytest.approx(d.error) and curve[d.step][1] == pytest.approx(d.tolerance)
    assert "TextLog" in rrd.blueprint_views and "TimeSeries" in rrd.blueprint_views


def test_without_a_stored_cause_the_events_and_growth_still_show(diverged, rrd_reader, tmp_path):
    """A replayed file that holds no explanation (another writer): the data part is shown, the cause is not."""
    import dataclasses

    from simreel.formats import open_reader, open_writer

    path, replayed, _ = diverged
    bare = tmp_path / "bare.h5"
    with open_reader(replayed) as r, open_writer(bare, r.meta) as w:
        episode = r.read_episode(0)
        w.write_episode(dataclasses.replace(episode, meta=dataclasses.replace(episode.meta, verification={})))
    out = tmp_path / "bare.rrd"
    with build_session(path, compare=bare, geometry="collision") as session:
        session.save(out)
    assert session.explanation.cause is None
    texts = [text[0] for _, text in rrd_reader(out).data["/events"]["TextLog:text"]]
    assert any(t.startswith("why: cause not classified: the replay holds no explanation") for t in texts)
    assert any(t.startswith("error: env_states/actors/cube[") for t in texts)


def test_a_replay_of_another_recording_lends_this_one_no_cause(diverged, rrd_reader, tmp_path):
    """The same episode under another recording's id (another run that stepped it): the replay explained its own
    recording's divergence, not this one's. Before: its stored cause was shown as this recording's, and the ghost was
    called the replay."""
    import dataclasses

    from simreel.formats import open_reader, open_writer
    from simreel.model.meta import new_recording_id

    path, replayed, _ = diverged
    other = tmp_path / "other.h5"
    with open_reader(path) as r, open_writer(other, dataclasses.replace(r.meta, recording_id=new_recording_id())) as w:
        w.write_episode(r.read_episode(0))
    out = tmp_path / "other.rrd"
    with build_session(other, compare=replayed, geometry="collision") as session:
        session.save(out)
    assert session.divergence is not None and session.explanation.cause is None
    texts = [text[0] for _, text in rrd_reader(out).data["/events"]["TextLog:text"]]
    assert ("why: cause not classified: the compared file is no replay of this recording (`simreel replay -o` "
            "classifies the cause of its replays' divergences)") in texts
    assert "compared with replayed.h5 episode 0: diverged" in texts
