"""The JSON sidecar beside a simreel .h5 (what ManiSkill's tools read instead of the .h5's own metadata): one that
disagrees with the .h5 — fewer or more episodes, other seeds, lengths or control mode — is named in one line by
`inspect` and `recover`, and `recover` rewrites it; a current one says nothing."""

from __future__ import annotations

import json
import shutil

import pytest

from simreel.cli.main import main
from simreel.formats import open_reader


def _edit_entries(doc, change):
    for entry in doc["episodes"]:
        change(entry)


def _more(doc):
    doc["episodes"] += [{**doc["episodes"][-1], "episode_id": i} for i in (3, 4)]  # another run's sidecar


def _seeds(doc):
    def shift(entry):
        entry["episode_seed"] += 5
        entry["reset_kwargs"]["seed"] += 5
    _edit_entries(doc, shift)


def _control_mode(doc):
    doc["env_info"]["env_kwargs"]["control_mode"] = "pd_ee_delta_pose"
    _edit_entries(doc, lambda entry: entry.update(control_mode="pd_ee_delta_pose"))


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (_more, "lists 5 episodes, 2 of them not in the .h5 (traj_3, traj_4: ManiSkill's tools fail there)"),
        (_seeds, "says episodes[0].episode_seed 8 where the .h5 says 3"),
        (_control_mode, 'says env_info.env_kwargs.control_mode "pd_ee_delta_pose" where the .h5 says '
                        '"pd_joint_delta_pos"'),
        (lambda doc: doc["episodes"][2].update(elapsed_steps=9), "says episodes[2].elapsed_steps 9 where the .h5 says 5"),
        (lambda doc: doc["episodes"].pop(), "lists 2 of the 3 episodes"),
    ],
    ids=["more-episodes", "other-seeds", "other-control-mode", "other-length", "fewer-episodes"],
)
def test_a_sidecar_that_disagrees_with_the_h5_is_named_and_recover_rewrites_it(record, tmp_path, capsys, change,
                                                                                  says):
    path = tmp_path / "rec.h5"
    shutil.copy(record("PickCube-v1", 3, 5), path)
    shutil.copy(record("PickCube-v1", 3, 5).with_suffix(".json"), path.with_suffix(".json"))
    current = json.loads(path.with_suffix(".json").read_text())
    doc = json.loads(path.with_suffix(".json").read_text())
    change(doc)
    path.with_suffix(".json").write_text(json.dumps(doc))
    note = f"note: its JSON sidecar (for ManiSkill's tools) {says}; `simreel recover {path}` rewrites it\n"

    assert main(["inspect", str(path)]) == 0
    assert capsys.readouterr().out.count(note) == 1
    assert main(["recover", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"recovered 3 committed episode(s), 15 steps, into {path}") and f"found: {note[6:]}" in out
    assert json.loads(path.with_suffix(".json").read_text())["episodes"] == current["episodes"]
    assert main(["recover", str(path)]) == 0
    assert "is complete (3 episode(s), 15 steps): nothing to recover" in capsys.readouterr().out


def test_a_current_sidecar_in_another_order_says_nothing(record, tmp_path):
    """ManiSkill's tools find an episode by its id, so a sidecar listing them in another order (commits of parallel
    envs end in any order) agrees with the .h5."""
    path = tmp_path / "rec.h5"
    shutil.copy(record("PickCube-v1", 3, 5), path)
    doc = json.loads(record("PickCube-v1", 3, 5).with_suffix(".json").read_text())
    doc["episodes"].reverse()
    path.with_suffix(".json").write_text(json.dumps(doc))
    with open_reader(path) as r:
        assert r.notes == []
