"""The audit's comparisons: the findings they add, worded with what differs and why."""

from __future__ import annotations

import numpy as np

from simreel.model.components import Tolerances
from simreel.replay.audit.checks import AuditReport, Check, compare_states, differing_attributes


def test_audit_names_a_key_missing_after_the_restore():
    report = AuditReport(env_id="X-v1", seed=0, steps=1)
    a = np.zeros((1, 3), np.float32)
    check = Check("restore_state", Tolerances.for_mode("states"), why="why")
    compare_states(report, check, {"gone": a, "kept": a}, {"kept": a, "new": a})
    details = {f.key: f.detail for f in report.findings}
    assert details["env_states/gone"] == "state key 'gone' missing after the restore: why"
    assert details["env_states/new"] == "state key 'new' present only after the restore: why"


def test_task_attributes_that_differ_include_plain_numbers():
    """A leak held in a plain Python number (`self.scale = float(...)`) was not named in the finding's hint; tensors,
    arrays and numbers that differ are, those equal and the state dict's own keys are not."""
    import types

    import torch

    a = types.SimpleNamespace(scale=0.25, count=3, done=False, goal=torch.zeros(3), same=1.5, cube=torch.ones(1))
    b = types.SimpleNamespace(scale=0.75, count=4, done=True, goal=torch.ones(3), same=1.5, cube=torch.zeros(1))
    assert differing_attributes(a, b, ["cube/p"]) == ["count", "done", "goal", "scale"]
