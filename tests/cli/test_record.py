"""`simreel record`: real runs, its output kept without --overwrite, seeded and user policies."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from simreel.cli.main import main


def _simreel(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simreel", *args], capture_output=True, text=True)


def test_record_then_inspect(tmp_path, capsys):
    out = tmp_path / "pc.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "-n", "2", "--seed", "7", "--max-steps", "10", "-q"]) == 0
    assert "recorded 2 episode(s), 20 steps" in capsys.readouterr().out
    assert main(["inspect", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [e["seed"] for e in summary["episodes"]] == [7, 8]
    assert summary["total_steps"] == 20
    assert summary["meta"]["state_layout"]["actors/cube"] == {"shape": [13], "dtype": "float32"}
    assert summary["meta"]["command"].startswith(f"simreel record PickCube-v1 -o {out} -n 2")
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "env_states/actors/cube" in text and "PickCube-v1" in text


def test_max_steps_is_the_time_limit_even_past_the_tasks_and_the_replay_keeps_it(tmp_path, capsys):
    out = tmp_path / "long.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "--max-steps", "60", "-q"]) == 0  # PickCube's own: 50
    assert "recorded 1 episode(s), 60 steps" in capsys.readouterr().out
    assert main(["inspect", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["meta"]["max_episode_steps"] == 60
    assert main(["replay", str(out), "-q"]) == 0
    assert "1 of 1 episode(s) verified (1 exact" in capsys.readouterr().out


def test_random_policy_is_reproducible_from_the_seed(tmp_path, capsys):
    from simreel.formats import open_reader

    for name in ("a.h5", "b.h5"):
        assert main(["record", "PushCube-v1", "-o", str(tmp_path / name), "--seed", "4", "--max-steps", "6", "-q"]) == 0
    with open_reader(tmp_path / "a.h5") as a, open_reader(tmp_path / "b.h5") as b:
        assert (a.read_episode(0).actions == b.read_episode(0).actions).all()


def test_policy_from_a_file(tmp_path, capsys):
    (tmp_path / "my_policy.py").write_text(
        "import numpy as np\n\ndef still(env, obs):\n    return np.zeros(env.action_space.shape, np.float32)\n"
    )
    out = tmp_path / "p.h5"
    assert main(["record", "PushCube-v1", "-o", str(out), "--policy", f"{tmp_path}/my_policy.py:still",
                 "--max-steps", "3", "-q"]) == 0
    from simreel.formats import open_reader

    with open_reader(out) as r:
        assert not r.read_episode(0).actions.any()


def test_episodes_longer_than_the_time_limit_are_recorded_and_the_limit_is_said(tmp_path, capsys):
    """Regression: `--max-steps 5000` was silently capped at the env's time limit (50 for PickCube-v1), and
    `max_episode_steps` in --env-kwargs was refused; which limit applies was never said."""
    from simreel.formats import open_reader

    out = tmp_path / "long.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "--max-steps", "120", "-q"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("PickCube-v1's time limit is 50 steps; this recording sets it to 120 (the recording "
                              "keeps it, so replay uses it too)\n")
    with open_reader(out) as r:
        assert r.meta.max_episode_steps == 120 and r.episodes[0].length == 120
        assert r.read_episode(0).truncated.tolist() == [False] * 119 + [True]  # the raised limit ends it
    out = tmp_path / "kwargs.h5"
    assert main(["record", "PickCube-v1", "-o", str(out), "--env-kwargs", '{"max_episode_steps": 70}', "-q"]) == 0
    assert capsys.readouterr().out.startswith("PickCube-v1's time limit is 50 steps; this recording sets it to 70 ")
    with open_reader(out) as r:
        assert r.meta.max_episode_steps == 70 and r.episodes[0].length == 70 and "max_episode_steps" not in r.meta.env_kwargs
    assert main(["replay", str(out), "-q"]) == 0  # rebuilt with the recorded limit: bit-exact
    assert "1 of 1 episode(s) verified (1 exact" in capsys.readouterr().out
    assert main(["record", "PickCube-v1", "-o", str(tmp_path / "short.h5"), "--max-steps", "7", "-q"]) == 0
    assert capsys.readouterr().out.startswith("PickCube-v1's time limit is 50 steps; this recording sets it to 7 ")
    assert main(["record", "PickCube-v1", "-o", str(tmp_path / "own.h5"), "-q"]) == 0
    assert capsys.readouterr().out.startswith("episodes end at PickCube-v1's time limit of 50 steps, or earlier when "
                                              "the task ends them\n")


_LATE_FAILING_POLICY = """
import numpy as np
calls = 0

def late(env, obs):
    global calls
    calls += 1
    if calls == 14:  # step 3 of the second episode of 10 steps
        {failure}
    return np.zeros(env.action_space.shape, np.float32)
"""


@pytest.mark.parametrize("suffix", [".h5", ".mcap"])
@pytest.mark.parametrize(("failure", "said"), [
    ("raise ValueError('boom')", "--policy {policy} raised ValueError: boom (episode 1, step 3); fix the policy"),
    ("raise SystemExit(5)", "--policy {policy} called sys.exit(5) (episode 1, step 3); a policy returns actions, the "
                            "recording ends by itself"),
], ids=["raises", "sys.exit"])
def test_a_recording_an_error_stops_replaces_nothing_and_notes_the_episode_it_cut(tmp_path, capsys, suffix, failure,
                                                                                    said):
    """Regression: `--overwrite` replaced the old file by the stopped recording's (a policy error, Ctrl-C), whose
    last episode, cut short, looked like any other; a policy calling sys.exit ended `record` with its status."""
    from simreel.formats import open_reader

    out = tmp_path / f"rec{suffix}"
    assert main(["record", "PickCube-v1", "-o", str(out), "-n", "3", "--max-steps", "10", "-q"]) == 0
    old = out.read_bytes()
    (tmp_path / "late.py").write_text(_LATE_FAILING_POLICY.format(failure=failure))
    policy = f"{tmp_path}/late.py:late"
    capsys.readouterr()
    assert main(["record", "PickCube-v1", "-o", str(out), "--overwrite", "-n", "5", "--max-steps", "10", "-q",
                 "--policy", policy]) == 2
    printed = capsys.readouterr()
    assert printed.err.splitlines() == [f"simreel record: error: {said.format(policy=policy)}"]
    staged = tmp_path / f"rec{suffix}.partial" / f"rec{suffix}"
    assert printed.out.splitlines()[-1] == (f"stopped: 2 episode(s), 13 steps, 0 successful, in {staged}, beside {out}, "
                                            "which is unchanged (the new recording replaces it only once complete); "
                                            "episode 1 was cut short (noted in the file)")
    assert out.read_bytes() == old
    with open_reader(staged) as r:
        assert [m.length for m in r.episodes] == [10, 3]
        assert r.episodes[0].notes == []
        assert r.episodes[1].notes == [f"cut short: an error ({said.format(policy=policy)}) stopped the recording "
                                       "before this episode ended"]
    assert main(["inspect", str(out)]) == 0
    assert (f"a recording that was to replace this one stopped before it was complete; its committed episodes are in "
            f"{staged} (this file is unchanged)") in capsys.readouterr().out
    kept = staged.read_bytes()
    assert main(["record", "PickCube-v1", "-o", str(out), "--overwrite", "-n", "1", "--max-steps", "2", "-q"]) == 2
    assert capsys.readouterr().err.splitlines() == [  # the next --overwrite never deletes the kept recording
        f"simreel record: error: {staged} holds the episodes of a recording that stopped before it was complete; move "
        f"it out of {staged.parent} (or delete that folder) first: --overwrite replaces {out}, never that recording"]
    assert staged.read_bytes() == kept and out.read_bytes() == old


class _BatchedStandIn:
    """What `_record_batched` sees of a `RecordWrapper` over N parallel envs, for this machine, whose CPU sim runs one
    env (the real batched recorder is tested on the GPU sim: `tests/recorders/test_record_wrapper_gpu.py`): a reset
    commits the running episodes of the envs it resets and starts theirs (seed, env); every episode lasts `length`
    steps of its env."""

    def __init__(self, n: int, lengths: dict[int, int]) -> None:
        import types

        self.meta, self.n, self.lengths = types.SimpleNamespace(num_envs=n), n, lengths
        self.episodes_committed: list[tuple[int, int]] = []
        self.running: dict[int, list] = {}
        self.seeds: list[int] = []

    def reset(self, seed, options=None):
        idx = range(self.n) if options is None else [int(i) for i in options["env_idx"]]
        for i, s in zip(idx, seed, strict=True):
            if i in self.running:
                self.episodes_committed.append(tuple(self.running.pop(i)[:2]))
            self.running[i] = [s, i, 0]
            self.seeds.append(s)
        return np.zeros((self.n, 1)), {}

    def step(self, _action):
        import torch

        for episode in self.running.values():
            episode[2] += 1
        ended = torch.tensor([self.running[i][2] >= self.lengths.get(i, 10) for i in range(self.n)])
        return np.zeros((self.n, 1)), None, ended, torch.zeros(self.n, dtype=torch.bool), {}

    def discard_running(self):
        self.running.clear()


@pytest.mark.parametrize(("episodes", "lengths", "committed"), [
    (1, {}, [(0, 0)]),  # four episodes end together: one was asked for
    (2, {}, [(0, 0), (1, 1)]),
    (6, {0: 3}, [(0, 0), (4, 0), (5, 0), (1, 1), (2, 2), (3, 3)]),  # env 0 runs three while the others run one
])
def test_parallel_envs_record_exactly_the_episodes_asked_with_seeds_in_range(episodes, lengths, committed):
    """Regression: -n 1 --num-envs 4 committed 4 episodes, and a run near the top of the seed range handed ManiSkill
    seeds past 2**32 - 1 for episodes it then dropped."""
    from simreel.cli import record
    from simreel.cli.common import EnvOptions

    seed = 2**32 - max(episodes, 4)  # the highest first seed the options allow
    cmd = record.RecordRun(env_id="X", output="x.h5", episodes=episodes, seed=seed, max_steps=10, quiet=True)
    record._check_seeds(cmd, EnvOptions(num_envs=4))
    rec = _BatchedStandIn(4, lengths)
    policy = record._Policy("zero", lambda env, obs: np.zeros(1))
    record._record_batched(rec, policy, cmd, 10)
    assert [(s - seed, env) for s, env in rec.episodes_committed] == committed
    assert max(rec.seeds) <= 2**32 - 1


def test_off_a_terminal_progress_is_a_plain_line_now_and_then_and_a_short_run_shows_none(tmp_path, capsys,
                                                                                          monkeypatch):
    """Off a terminal (a log, CI) the progress bar is a plain line every `LOG_LINE_SECONDS` once the work has run that
    long: never a carriage return, the closing line not repeating the last count; a run shorter than that writes
    nothing to stderr. With the interval at 0 every episode is a line."""
    import re

    import simreel.cli.common as common

    args = ["record", "PickCube-v1", "-n", "3", "--max-steps", "5", "--render-backend", "none"]
    assert main([*args, "-o", str(tmp_path / "short.h5")]) == 0
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(common, "LOG_LINE_SECONDS", 0.0)
    assert main([*args, "-o", str(tmp_path / "logged.h5")]) == 0
    lines = capsys.readouterr().err.splitlines(keepends=True)
    assert [re.search(r"\| (\d)/3 \[", line).group(1) for line in lines] == ["0", "1", "2", "3"]
    assert all(line.startswith("record PickCube-v1: ") and "\r" not in line for line in lines)
