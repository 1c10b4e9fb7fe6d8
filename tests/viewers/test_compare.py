"""The viewer's use of the core comparison: rows of each key, the divergence's row, unequal lengths."""

from __future__ import annotations

import dataclasses

import numpy as np

from simreel.model.components import Tolerances
from simreel.model.episode import Episode
from simreel.model.meta import EpisodeMeta
from simreel.verdicts.compare import Divergence
from simreel.viewers.compare import compare_for_view, divergence_row


def _episode(steps: int) -> Episode:
    cube = np.zeros((steps + 1, 13), np.float32)
    cube[:, 3] = 1.0
    z = np.zeros(steps, bool)
    return Episode(EpisodeMeta(0, length=steps), np.zeros((steps, 2), np.float32), np.zeros(steps, np.float32),
                   z, z, z, z, {"actors/cube": cube})


def test_divergence_row():
    assert divergence_row(Divergence(0, "env_states/actors/cube[p]", 1.0, 0.1, at="reset")) == 0
    assert divergence_row(Divergence(143, "env_states/actors/cube[p]", 1.0, 0.1)) == 144


def test_quaternion_sign_and_rows_of_each_key():
    rec, rep = _episode(4), _episode(4)
    rep.env_states["actors/cube"][:, 3:7] *= -1  # the same rotation
    rep.env_states["actors/cube"][3, 1] += 0.5  # state row 3: the outcome of step 2
    rep.rewards[1] = 0.25
    c = compare_for_view(rec, rep)
    d = c.divergence  # the reward of step 1 parts first, at state row 2
    assert (d.step, d.key, divergence_row(d)) == (1, "rewards", 2)
    assert c.comparison.diverged_keys["env_states/actors/cube[p]"] == 2
    rows = c.error_rows()
    r, err, tol = rows["env_states/actors/cube[q]"]
    assert list(r) == [0, 1, 2, 3, 4] and err.max() == 0.0  # q ≡ -q
    r, err, tol = rows["rewards"]
    assert list(r) == [1, 2, 3, 4] and err[1] == 0.25  # reward of step 1 sits with state row 2
    assert "rewards" in c.plotted_keys() and "terminated" not in c.plotted_keys()
    assert "env_states/actors/cube[v]" not in c.plotted_keys()  # never off: not plotted


def test_unequal_lengths_compare_the_shorter():
    rec, rep = _episode(6), _episode(4)
    c = compare_for_view(rec, rep, tolerances=Tolerances.for_mode("actions", atol=1e-3))
    assert c.steps == 4 and "compared the first 4" in c.note
    assert c.divergence is None and c.comparison.verdict == "exact"
    assert c.comparison.tolerance["env_states/actors/cube[p]"] == 1e-3


def test_mode_tolerances():
    c = compare_for_view(_episode(2), dataclasses.replace(_episode(2)),
                         tolerances=Tolerances.for_mode("step", groups={"pos": 0.5}))
    assert c.comparison.tolerance["env_states/actors/cube[p]"] == 0.5
    assert c.comparison.tolerance["env_states/actors/cube[q]"] == 0.2  # step mode's quat default


def test_an_exact_replay_still_plots_its_state_keys():
    c = compare_for_view(_episode(3), _episode(3))
    assert c.comparison.verdict == "exact"
    assert c.plotted_keys() == ["env_states/actors/cube[p]", "env_states/actors/cube[q]",
                                "env_states/actors/cube[v]", "env_states/actors/cube[w]"]


def test_blocks_of_any_size_give_one_comparison():
    """Read in blocks of 2, 3 or all rows, with the replay shorter than the recording and parting in a late
    block, the comparison is the same; an episode of no steps still compares."""
    rec, rep = _episode(10), _episode(7)
    rep.env_states["actors/cube"][6, 0] += 0.5  # state row 6: the outcome of step 5
    results = []
    for rows in (2, 3, None):
        c = compare_for_view(rec, rep, rows=rows)
        d = c.divergence
        errors = {k: (list(r), err.tolist()) for k, (r, err, _) in c.error_rows().items()}
        results.append((c.steps, d.step, d.key, c.comparison.verdict, errors))
    assert results[0] == results[1] == results[2]
    assert results[0][:4] == (7, 5, "env_states/actors/cube[p]", "diverged")
    assert compare_for_view(_episode(0), _episode(0)).comparison.verdict == "exact"
