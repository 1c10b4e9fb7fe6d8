"""The `simreel` command as a whole: bad input to any command is one line and exit 2 (a table, run in-process),
no command replaces a file without --overwrite, no report replaces a recording or its sidecar even with it, an
internal error is exit 3, and `--help` is instant."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.unreadable import link_loop, unreadable_copy

from simreel.cli.main import main


def _run(capsys, argv: list[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own errors
        code = e.code
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def rec(record) -> Path:
    return record("PickCube-v1", 2, 20)


LOOP = "a symbolic link loop (following its links never reaches a file); fix or remove the link"
"""What a path that runs into a symbolic link loop is, read or written (`test_bad_input_is_one_line_and_exit_2` makes
loop.h5, loop.mcap, report_loop.json and loop.py loops)."""

BAD_INPUT = [
    # record
    ("record-unknown-env", ["record", "PickCub-v1", "-o", "{tmp}/x.h5"],
     "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1"),
    ("record-unknown-env-imported", ["record", "PickCub-v1", "-o", "{tmp}/x.h5", "--import", "{tmp}/no_tasks.py"],
     "{tmp}/no_tasks.py registers no env"),  # not "pass --import": it was passed
    ("record-unknown-body", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "panda/nose:cube"],
     "unknown body 'panda/nose'"),
    ("record-bad-pair", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "cube"], "bad contact pair 'cube'"),
    ("record-option-and-env-kwarg", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--obs-mode", "state",
                                     "--env-kwargs", '{{"obs_mode": "state_dict"}}'],  # was: state_dict, without a word
     "PickCube-v1: obs_mode is given twice, 'state' and 'state_dict' in env_kwargs (--env-kwargs); give it once"),
    ("record-no-dir", ["record", "PickCube-v1", "-o", "{tmp}/no/such/dir/x.h5"], "does not exist"),
    ("record-bad-suffix", ["record", "PickCube-v1", "-o", "{tmp}/x.txt"], "unknown recording suffix '.txt'"),
    ("record-bad-policy", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "nosuchmod:f"],
     "cannot import nosuchmod"),
    ("record-zero-episodes", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "-n", "0"], "--episodes must be ≥ 1"),
    ("record-non-int", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "-n", "two"],
     "argument -n/--episodes: invalid int value"),
    ("record-bad-json", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--env-kwargs", "[1]"], "expected a JSON object"),
    ("record-json-nan", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--env-kwargs", '{{"sim_config": {{"x": NaN}}}}'],
     "argument --env-kwargs: not valid JSON (NaN is no JSON number; give a finite number)"),  # was: taken, then
    # ManiSkill's AttributeError, or NaN written into the recording's metadata
    ("record-bad-import", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--import", "{tmp}/missing.py"], "missing.py"),
    ("record-broken-policy-file", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/broken.py:f"],
     "broken.py"),
    ("record-multi-agent", ["record", "TwoRobotPickCube-v1", "-o", "{tmp}/x.h5"],
     "Dict action space (a multi-agent task)"),
    # record: seeds ManiSkill refuses, policies that fail or return what no env takes (issue 17, item 8)
    ("record-negative-seed", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--seed", "-1"],
     "--seed -1: this run would use seeds -1 to -1, but ManiSkill takes seeds from 0 to 4294967295"),
    ("record-seed-past-2**32", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--seed", "4294967295", "-n", "2"],
     "this run would use seeds 4294967295 to 4294967296"),
    ("record-episodes-past-seeds", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "-n", "99999999999999999999999"],
     "seeds 0 to 99999999999999999999998, but ManiSkill takes seeds from 0 to 4294967295; choose a seed, or fewer "
     "episodes (-n), that keeps them in that range"),  # was: "choose a seed in that range", -n not named
    ("record-policy-raises", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:boom"],
     "policies.py:boom raised RuntimeError: policy bug (episode 0, step 0); fix the policy"),
    ("record-policy-shape", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:short"],
     "policies.py:short returned an action of shape (3,); PickCube-v1 takes shape (8,) (episode 0, step 0)"),
    ("record-policy-nan", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:nan"],
     "policies.py:nan returned an action holding NaN or infinity"),
    ("record-policy-none", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:none"],
     "policies.py:none returned an action of type NoneType; PickCube-v1 takes a numeric array of shape (8,)"),
    ("record-policy-list", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:listed"],
     "policies.py:listed returned an action of type list; PickCube-v1 takes a numeric array of shape (8,)"),
    ("record-time-limit-kwarg", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--env-kwargs", '{{"max_episode_steps": 0}}'],
     "--env-kwargs max_episode_steps must be a whole number from 1 to 2147483647 (ManiSkill counts steps in 32 bits), "
     "got 0"),
    ("record-time-limit-past-int32", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--max-steps", "2147483648"],
     "--max-steps must be from 1 to 2147483647 (ManiSkill counts steps in 32 bits), got 2147483648"),
    ("record-policy-exits", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--policy", "{tmp}/policies.py:leave"],
     "policies.py:leave called sys.exit(5) (episode 0, step 0); a policy returns actions, the recording ends by "
     "itself"),
    ("record-contacts-self", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "cube:cube"],
     "bad contact pair 'cube:cube': a body paired with itself"),
    ("record-contacts-twice", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", "cube:table-workspace,"
     "cube:table-workspace"], "contact pair 'cube:table-workspace' is named twice"),
    ("record-contacts-empty", ["record", "PickCube-v1", "-o", "{tmp}/x.h5", "--contacts", ","],
     "contacts ',' names no pair; give auto, none or pairs like panda/panda_leftfinger:cube"),
    ("record-o-loop", ["record", "PickCube-v1", "-o", "{tmp}/loop.h5"], "cannot write {tmp}/loop.h5: " + LOOP),
    ("record-o-loop-mcap", ["record", "PickCube-v1", "-o", "{tmp}/loop.mcap", "--overwrite"],
     "cannot write {tmp}/loop.mcap: " + LOOP),
    # inspect
    ("inspect-missing", ["inspect", "{tmp}/missing.h5"], "missing.h5: no such file"),
    ("inspect-junk", ["inspect", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
    ("inspect-empty-folder", ["inspect", "{tmp}/empty"], "no recordings (.h5, .hdf5, .mcap) found in this folder"),
    ("inspect-loop", ["inspect", "{tmp}/loop.h5"], "{tmp}/loop.h5: " + LOOP),
    # replay
    ("replay-missing", ["replay", "{tmp}/nope.h5"], "nope.h5: no such file"),
    ("replay-junk", ["replay", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
    ("replay-loop", ["replay", "{tmp}/loop.mcap"], "{tmp}/loop.mcap: " + LOOP),
    ("replay-report-loop", ["replay", "{rec}", "--report", "{tmp}/report_loop.json"],
     "cannot write --report {tmp}/report_loop.json: " + LOOP),
    ("replay-no-episode", ["replay", "{rec}", "--episodes", "7"], "no episode 7 (episodes: 0, 1)"),
    ("replay-bad-episodes", ["replay", "{rec}", "--episodes", "x"], "bad episode list 'x'"),
    ("replay-empty-path", ["replay", ""], "an empty path names no recording"),  # was: every recording in the folder
    ("inspect-name-too-long", ["inspect", "{tmp}/" + "z" * 300 + ".h5"],  # was: exit 3, OSError
     "a name in this path is longer than the file system takes"),
    ("convert-name-too-long", ["convert", "{tmp}/" + "z" * 300 + ".h5", "{tmp}/out.mcap"],
     "a name in this path is longer than the file system takes"),
    ("inspect-empty-path", ["inspect", "{rec}", " "], "an empty path names no recording"),
    ("replay-huge-episodes", ["replay", "{rec}", "--episodes", "0-99999999999999999999"],
     "no episode 2 (episodes: 0, 1)"),  # a range is walked to the file's first gap, never built
    ("replay-episodes-underscore", ["replay", "{rec}", "--episodes", "1_0"],
     "bad episode list '1_0': expected e.g. 0,3-7"),  # int() reads 10 there: digits only
    ("replay-episodes-sign", ["replay", "{rec}", "--episodes", "+1"], "bad episode list '+1'"),
    ("replay-resync-mode", ["replay", "{rec}", "--mode", "states", "--resync", "5"],
     "--resync works with --mode actions only"),
    ("replay-resync-0", ["replay", "{rec}", "--resync", "0"], "--resync must be >= 1, got 0"),
    ("replay-workers-0", ["replay", "{rec}", "--workers", "0"], "--workers must be >= 1, got 0"),
    ("replay-ship-no-ray", ["replay", "{rec}", "--ship"], "--ship works with --ray only"),  # was: ignored, exit 0
    ("replay-atol", ["replay", "{rec}", "--atol", "-1"], "argument --atol: '-1': a tolerance must be a finite number >= 0"),
    ("replay-tol", ["replay", "{rec}", "--tol", "speed=1"], "expected GROUP=NUMBER with GROUP one of pos"),
    ("replay-mode", ["replay", "{rec}", "--mode", "sideways"], "argument --mode: invalid choice: 'sideways'"),
    ("replay-o-is-input", ["replay", "{rec}", "-o", "{rec}", "--overwrite"], "is a recording being replayed"),
    ("replay-o-exists", ["replay", "{rec}", "-o", "{tmp}/exists.h5"], "exists.h5 already exists; pass --overwrite"),
    ("replay-o-suffix", ["replay", "{rec}", "-o", "{tmp}/out.txt"], "unknown recording suffix '.txt'"),
    ("replay-report-no-dir", ["replay", "{rec}", "--report", "{tmp}/no/dir/r.json"], "does not exist"),
    ("replay-report-is-o-sidecar", ["replay", "{rec}", "-o", "{tmp}/out.h5", "--report", "{tmp}/out.json"],
     "--report {tmp}/out.json is also written by -o"),
    ("replay-bad-import", ["replay", "{rec}", "--import", "no_such_module_xyz"],
     "no module named 'no_such_module_xyz'"),
    ("replay-import-loop", ["replay", "{rec}", "--import", "{tmp}/loop.py"], "--import {tmp}/loop.py: " + LOOP),
    ("replay-nothing", ["replay"], "name the recordings to replay (files, folders, patterns), or --resume"),
    ("replay-empty-folder", ["replay", "{tmp}/empty"], "empty: no recordings (.h5, .hdf5, .mcap) found in this folder"),
    ("replay-no-match", ["replay", "{tmp}/*.mcap"], "no recordings (.h5, .hdf5, .mcap) found in this pattern"),
    ("replay-o-many", ["replay", "{rec}", "{rec2}", "-o", "{tmp}/out.h5"],
     "-o writes the replayed episodes of one recording; name one file to replay"),
    ("replay-report-suffix", ["replay", "{rec}", "--report", "{tmp}/r.txt"], "a report is a .json file"),
    ("replay-resume-missing", ["replay", "--resume", "{tmp}/none.json"], "none.jsonl: no such report"),
    ("replay-resume-junk", ["replay", "--resume", "{tmp}/junk.json"], "junk.jsonl: line 1 is not JSON"),
    ("replay-resume-and-path", ["replay", "{rec}", "--resume", "{tmp}/junk.json"],
     "--resume takes the recordings and options from the report; drop PATH"),
    ("replay-resume-and-mode", ["replay", "--resume", "{tmp}/junk.json", "--mode", "step"], "drop --mode"),
    # audit
    ("audit-unknown-env", ["audit", "PickCub-v1"], "unknown ManiSkill env id 'PickCub-v1': did you mean PickCube-v1"),
    ("audit-steps-0", ["audit", "PickCube-v1", "--steps", "0"], "--steps must be >= 1, got 0"),
    ("audit-json-no-dir", ["audit", "PickCube-v1", "--json", "{tmp}/no/dir/a.json"], "does not exist"),
    ("audit-set-state-raises", ["audit", "TestBadSetState-v1", "--steps", "2", "--import", "{tmp}/bad_tasks.py"],
     "BadSetState.set_state_dict raised KeyError: 'nope' while a state was restored into it; fix the task's "
     "set_state_dict"),
    ("audit-policy-raises", ["audit", "PickCube-v1", "--steps", "2", "--policy", "{tmp}/policies.py:boom"],
     "--policy {tmp}/policies.py:boom raised RuntimeError: policy bug; fix the policy"),
    ("audit-policy-list", ["audit", "PickCube-v1", "--steps", "2", "--policy", "{tmp}/policies.py:listed"],
     "--policy {tmp}/policies.py:listed returned an action of type list; PickCube-v1 takes a numeric array of shape "
     "(8,)"),
    # view
    ("view-no-episode", ["view", "{rec}", "--episode", "7"], "no episode 7 (episodes: 0, 1)"),
    ("view-save-suffix", ["view", "{rec}", "--save", "x.png"], "--save x.png: the output must be a file name ending in .rrd"),
    ("view-block-steps", ["view", "{rec}", "--block-steps", "0"], "--block-steps must be ≥ 1, got 0"),
    ("view-loop", ["view", "{tmp}/loop.h5", "--save", "{tmp}/v.rrd"], "{tmp}/loop.h5: " + LOOP),
    ("view-compare-missing", ["view", "{rec}", "--compare", "{tmp}/missing.h5", "--save", "{tmp}/v.rrd"],
     "missing.h5: no such file"),
    # convert
    ("convert-suffix", ["convert", "{rec}", "{tmp}/out.txt"], "unknown recording suffix '.txt'"),
    ("convert-missing", ["convert", "{tmp}/missing.h5", "{tmp}/out.mcap"], "missing.h5: no such file"),
    ("convert-folder", ["convert", "{tmp}", "{tmp}/out.mcap"], ": a folder, not a recording file"),
    ("convert-loop", ["convert", "{tmp}/loop.mcap", "{tmp}/out.h5"], "{tmp}/loop.mcap: " + LOOP),
    ("convert-o-loop", ["convert", "{rec}", "{tmp}/loop.mcap", "--overwrite"], "cannot write {tmp}/loop.mcap: " + LOOP),
    ("inspect-device", ["inspect", "/dev/null"], "/dev/null: not a regular file"),
    ("convert-same", ["convert", "{rec}", "{rec}"], "OUT {rec} is IN; write it to another file"),
    ("convert-name-too-long", ["convert", "{rec}", "{tmp}/" + "x" * 300 + ".mcap"],
     "its name is 305 bytes long, and the file system takes names of 255 bytes at most; choose a shorter name"),
    ("convert-o-shares-sidecar", ["convert", "{rec}", "{rec_twin}", "--overwrite"], "is a file of IN"),
    # recover
    ("recover-junk", ["recover", "{tmp}/junk.h5"], "neither an HDF5 nor an MCAP file"),
    ("recover-missing", ["recover", "{tmp}/missing.mcap"], "missing.mcap: no such file"),
    ("recover-loop", ["recover", "{tmp}/loop.mcap"], "{tmp}/loop.mcap: " + LOOP),
    ("recover-o-loop", ["recover", "{rec}", "-o", "{tmp}/loop.h5"], "cannot write {tmp}/loop.h5: " + LOOP),
    ("recover-o-shares-sidecar", ["recover", "{rec}", "-o", "{rec_twin}", "--overwrite"],
     "is a file of the recording to recover"),
    # merge
    ("merge-no-o", ["merge", "{rec}"], "the following arguments are required: -o/--output"),
    ("merge-missing", ["merge", "{rec}", "{tmp}/missing.h5", "-o", "{tmp}/out.h5"], "missing.h5: no such file"),
    ("merge-junk", ["merge", "{rec}", "{tmp}/junk.h5", "-o", "{tmp}/out.h5"], "neither an HDF5 nor an MCAP file"),
    ("merge-loop", ["merge", "{rec}", "{tmp}/loop.h5", "-o", "{tmp}/out.h5"], "{tmp}/loop.h5: " + LOOP),
    ("merge-o-loop", ["merge", "{rec}", "-o", "{tmp}/loop.h5"], "cannot write {tmp}/loop.h5: " + LOOP),
    ("merge-o-is-input", ["merge", "{rec}", "{tmp}/junk.h5", "-o", "{rec}", "--overwrite"], "is input {rec}"),
    ("merge-twice", ["merge", "{rec}", "{rec}", "-o", "{tmp}/out.h5"], "is given twice; each input is merged once"),
    ("merge-other-env", ["merge", "{rec}", "{tmp}/other.h5", "-o", "{tmp}/out.h5"],
     "{tmp}/other.h5 records another env than {rec}: env_id is 'Synthetic-v0' there, 'PickCube-v1' in {rec}"),
    ("merge-suffix", ["merge", "{rec}", "-o", "{tmp}/out.txt"], "unknown recording suffix '.txt'"),
    ("merge-folder-name-too-long", ["merge", "{rec}", "-o", "{tmp}/" + "z" * 300 + "/m.h5"],
     "a folder name in it is 300 bytes long, and the file system takes names of 255 bytes at most"),
    ("merge-side-name-too-long", ["merge", "{rec}", "-o", "{tmp}/" + "v" * 250 + ".h5"],
     "the name of the .partial file beside it is 261 bytes long"),  # the HDF5 file's folder of unfinished episodes
    # filter
    ("filter-no-criterion", ["filter", "{rec}", "-o", "{tmp}/out.h5"], "no criterion: give --episodes"),
    ("filter-no-episode", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--episodes", "7"],
     "no episode 7 (episodes: 0, 1)"),
    ("filter-huge-episodes", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--episodes", "1-99999999999999999999"],
     "no episode 2 (episodes: 0, 1)"),
    ("filter-episodes-underscore", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--episodes", "0_1"],
     "bad episode list '0_1'"),
    ("filter-nothing-kept", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--min-steps", "21"], "nothing matches"),
    ("filter-min-max", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--min-steps", "9", "--max-steps", "1"],
     "--min-steps 9 is above --max-steps 1"),
    ("filter-rest-is-o", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--success", "--rest", "{tmp}/out.h5"],
     "--rest {tmp}/out.h5 is also written by -o"),
    ("filter-missing", ["filter", "{tmp}/missing.mcap", "-o", "{tmp}/out.h5", "--success"],
     "missing.mcap: no such file"),
    ("filter-loop", ["filter", "{tmp}/loop.h5", "-o", "{tmp}/out.h5", "--success"], "{tmp}/loop.h5: " + LOOP),
    ("filter-o-loop", ["filter", "{rec}", "-o", "{tmp}/loop.mcap", "--success"], "cannot write {tmp}/loop.mcap: " + LOOP),
]


@pytest.fixture(scope="module")
def recs(rec, record) -> dict[str, Path]:
    """{rec} and {rec2} of the table: two recordings; {rec_twin}: a path beside {rec} that would share its JSON sidecar
    (never written: every case refuses it)."""
    return {"rec": rec, "rec2": record("PickCube-v1", 1, 10), "rec_twin": rec.with_suffix(".hdf5")}


POLICIES = """import numpy as np
def boom(env, obs): raise RuntimeError("policy bug")
def short(env, obs): return np.zeros(3, np.float32)
def nan(env, obs): return np.full(env.action_space.shape, np.nan, np.float32)
def none(env, obs): return None
def listed(env, obs): return [0.0] * 8
def leave(env, obs): raise SystemExit(5)
"""


BAD_TASKS = """from mani_skill.envs.tasks.tabletop.pick_cube import PickCubeEnv
from mani_skill.utils.registration import register_env

@register_env("TestBadSetState-v1", max_episode_steps=50)
class BadSetState(PickCubeEnv):
    def set_state_dict(self, state, env_idx=None):
        raise KeyError("nope")
"""


@pytest.mark.parametrize(("argv", "message"), [case[1:] for case in BAD_INPUT], ids=[case[0] for case in BAD_INPUT])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, recs, argv, message):
    (tmp_path / "junk.h5").write_text("not a recording")
    (tmp_path / "junk.jsonl").write_text("not a report\n")
    (tmp_path / "exists.h5").write_bytes(b"")
    (tmp_path / "broken.py").write_text("raise RuntimeError('oops')\n")
    (tmp_path / "empty").mkdir()
    (tmp_path / "no_tasks.py").write_text("VALUE = 1\n")
    (tmp_path / "policies.py").write_text(POLICIES)
    (tmp_path / "bad_tasks.py").write_text(BAD_TASKS)
    if any("loop" in a for a in argv):
        for loop in ("loop.h5", "loop.mcap", "report_loop.json", "loop.py"):
            link_loop(tmp_path / loop)
    if any("other.h5" in a for a in argv):
        from support.mcap_samples import synthetic_episode, synthetic_meta, write

        write(tmp_path / "other.h5", synthetic_meta(), [synthetic_episode(synthetic_meta(), 0, 3)])
    argv = [a.format(tmp=tmp_path, **recs) for a in argv]
    quiet = argv[0] in ("record", "replay", "convert", "merge", "filter")
    code, err = _run(capsys, [*argv, "-q"] if quiet else argv)
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert message.format(tmp=tmp_path, **recs) in err


# A recording this user may not read, whichever command reads it: one line naming it and why, exit 2. Run as a shell
# would, where the file's mode bites (for root, without the capabilities that read any file: `support.unreadable`).
UNREADABLE = [
    ("inspect", ["inspect", "{tmp}/nr.h5"]),
    ("inspect-mcap", ["inspect", "{tmp}/nr.mcap"]),
    ("replay", ["replay", "{tmp}/nr.h5", "-q"]),
    ("convert", ["convert", "{tmp}/nr.mcap", "{tmp}/out.h5", "-q"]),
    ("merge", ["merge", "{rec}", "{tmp}/nr.h5", "-o", "{tmp}/out.h5", "-q"]),
    ("filter", ["filter", "{tmp}/nr.mcap", "-o", "{tmp}/out.h5", "--success", "-q"]),
    ("recover", ["recover", "{tmp}/nr.mcap"]),
    ("view", ["view", "{tmp}/nr.h5", "--save", "{tmp}/v.rrd"]),
    ("video", ["video", "{tmp}/nr.mcap", "-o", "{tmp}"]),
]


@pytest.fixture(scope="module")
def rec_mcap(rec, tmp_path_factory) -> Path:
    """{rec} converted to MCAP."""
    out = tmp_path_factory.mktemp("mcap") / "rec.mcap"
    assert main(["convert", str(rec), str(out), "-q"]) == 0
    return out


@pytest.mark.parametrize("argv", [c[1] for c in UNREADABLE], ids=[c[0] for c in UNREADABLE])
def test_a_recording_this_user_may_not_read_is_one_line_and_exit_2(tmp_path, rec, rec_mcap, argv):
    """Regression: the reader's open() raised PermissionError, which the CLI took for a bug of simreel's (exit 3)."""
    prefix = unreadable_copy(rec, tmp_path / "nr.h5")
    unreadable_copy(rec_mcap, tmp_path / "nr.mcap")
    argv = [a.format(tmp=tmp_path, rec=rec) for a in argv]
    done = subprocess.run([*prefix, sys.executable, "-m", "simreel", *argv], capture_output=True, text=True,
                          timeout=120)
    unreadable = next(a for a in argv if "/nr." in a)
    assert (done.returncode, done.stderr) == (
        2, f"simreel {argv[0]}: error: {unreadable}: permission denied (this user may not read it)\n")


# Every command that writes, and every file it would write: an existing one is refused without --overwrite,
# named in the one line, and left as it was.
EXISTING_OUTPUT = [
    ("record", ["record", "PushCube-v1", "-o", "{tmp}/out.h5", "--max-steps", "2"], "out.h5"),
    ("record-sidecar", ["record", "PushCube-v1", "-o", "{tmp}/out.h5", "--max-steps", "2"], "out.json"),
    ("record-mcap", ["record", "PushCube-v1", "-o", "{tmp}/out.mcap", "--max-steps", "2"], "out.mcap"),
    ("replay-o", ["replay", "{rec}", "-o", "{tmp}/out.h5"], "out.h5"),
    ("replay-o-sidecar", ["replay", "{rec}", "-o", "{tmp}/out.h5"], "out.json"),
    ("replay-o-partial", ["replay", "{rec}", "-o", "{tmp}/out.h5"], "out.h5.partial"),
    ("replay-report", ["replay", "{rec}", "--report", "{tmp}/report.json"], "report.json"),
    ("replay-report-stream", ["replay", "{rec}", "--report", "{tmp}/report.json"], "report.jsonl"),
    ("convert", ["convert", "{rec}", "{tmp}/out.mcap"], "out.mcap"),
    ("convert-sidecar", ["convert", "{rec}", "{tmp}/out.h5"], "out.json"),
    ("recover-o", ["recover", "{cut}", "-o", "{tmp}/out.mcap"], "out.mcap"),
    ("view-save", ["view", "{rec}", "--save", "{tmp}/out.rrd", "--geometry", "collision"], "out.rrd"),
    ("audit-json", ["audit", "PickCube-v1", "--steps", "2", "--json", "{tmp}/audit.json"], "audit.json"),
    ("merge", ["merge", "{rec}", "-o", "{tmp}/out.mcap"], "out.mcap"),
    ("merge-sidecar", ["merge", "{rec}", "-o", "{tmp}/out.h5"], "out.json"),
    ("filter", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--success"], "out.h5"),
    ("filter-rest", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--episodes", "0", "--rest", "{tmp}/rest.mcap"],
     "rest.mcap"),
    ("filter-rest-partial", ["filter", "{rec}", "-o", "{tmp}/out.h5", "--episodes", "0", "--rest", "{tmp}/rest.h5"],
     "rest.h5.partial"),
]


@pytest.mark.parametrize(("argv", "existing"), [c[1:] for c in EXISTING_OUTPUT], ids=[c[0] for c in EXISTING_OUTPUT])
def test_no_command_replaces_a_file_without_overwrite(tmp_path, capsys, rec, argv, existing):
    from support.mcap_samples import synthetic_episode, synthetic_meta, write

    cut = write(tmp_path / "cut.mcap", synthetic_meta(), [synthetic_episode(synthetic_meta(), 0, 3)])
    cut.write_bytes(cut.read_bytes()[:-40])  # no footer: what a killed recording leaves
    target = tmp_path / existing
    if existing.endswith(".partial"):
        target.mkdir()
        (target / "traj_0.h5").write_bytes(b"mine")
    else:
        target.write_bytes(b"mine")
    argv = [a.format(tmp=tmp_path, rec=rec, cut=cut) for a in argv]
    code, err = _run(capsys, argv)
    assert code == 2, err
    assert err.count("\n") == 1 and f"{target} already exists" in err and "pass --overwrite" in err, err
    kept = target / "traj_0.h5" if target.is_dir() else target
    assert kept.read_bytes() == b"mine"


# A report (audit --json, replay --report, convert --report) never replaces a recording the command reads nor a file
# of it, nor the JSON sidecar another recording keeps beside it (ManiSkill's tools read the two together), even with
# --overwrite: every case is refused before any work, in one line, and leaves every file as it was.
REPORT_ONTO_RECORDING = [
    ("audit-json-is-trajectory", ["audit", "--trajectory", "{mine}", "--episodes", "0", "--json", "{mine}"],
     "--json {mine} is the --trajectory recording; write it to another file"),
    ("audit-json-is-trajectory-sidecar", ["audit", "--trajectory", "{mine}", "--episodes", "0", "--json",
                                          "{mine_sidecar}"],
     "--json {mine_sidecar} is a file of the --trajectory recording; write it to another file"),
    ("audit-json-other-sidecar", ["audit", "--trajectory", "{mine}", "--episodes", "0", "--json", "{other_sidecar}"],
     "{other_sidecar} is the JSON sidecar of {other}, which ManiSkill's tools read with it; writing --json "
     "{other_sidecar} would replace it: name the output otherwise"),
    ("audit-json-hdf5-sidecar", ["audit", "PickCube-v1", "--steps", "2", "--json", "{twin_sidecar}"],
     "{twin_sidecar} is the JSON sidecar of {twin}"),
    ("replay-report-other-sidecar", ["replay", "{mine}", "--report", "{other_sidecar}", "-q"],
     "{other_sidecar} is the JSON sidecar of {other}, which ManiSkill's tools read with it; writing --report "
     "{other_sidecar} would replace it: name the output otherwise"),
    ("replay-report-hdf5-sidecar", ["replay", "{mine}", "--report", "{twin_sidecar}", "-q"],
     "{twin_sidecar} is the JSON sidecar of {twin}"),
    ("convert-report-other-sidecar", ["convert", "{mine}", "{tmp}/out.h5", "--obs-mode", "state", "--report",
                                      "{other_sidecar}", "-q"],
     "{other_sidecar} is the JSON sidecar of {other}, which ManiSkill's tools read with it; writing --report "
     "{other_sidecar} would replace it: name the output otherwise"),
]


@pytest.mark.parametrize(("argv", "message"), [c[1:] for c in REPORT_ONTO_RECORDING],
                         ids=[c[0] for c in REPORT_ONTO_RECORDING])
def test_no_report_replaces_a_recording_or_its_sidecar_even_with_overwrite(tmp_path, capsys, rec, argv, message):
    """Regression: `audit --trajectory x.h5 --json x.h5 --overwrite` replaced the recording it audited with its
    report, and a --json/--report named like another recording's sidecar replaced that sidecar."""
    import shutil

    names = {"mine": "mine.h5", "other": "other.h5", "twin": "twin.hdf5"}
    paths = {}
    for key, name in names.items():
        paths[key] = shutil.copy(rec, tmp_path / name)
        paths[f"{key}_sidecar"] = shutil.copy(rec.with_suffix(".json"), (tmp_path / name).with_suffix(".json"))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    argv = [a.format(tmp=tmp_path, **paths) for a in [*argv, "--overwrite"]]
    code, err = _run(capsys, argv)
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert message.format(tmp=tmp_path, **paths) in err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # nothing replaced, nothing written


@pytest.mark.parametrize(("argv", "message"), [
    (["inspect", "-x.h5"], "simreel inspect: error: the following arguments are required: PATH (-x.h5 is taken for an "
                           "option: write ./-x.h5 for the file; see simreel inspect --help)"),
    (["convert", "a.h5", "-y.mcap"], "simreel convert: error: the following arguments are required: OUT (-y.mcap is "
                                     "taken for an option: write ./-y.mcap for the file; see simreel convert --help)"),
    (["record", "PickCube-v1", "-o", "-z.h5"], "simreel record: error: argument -o/--output: expected one argument "
                                               "(-z.h5 is taken for an option: write ./-z.h5 for the file; see simreel "
                                               "record --help)"),
    (["inspect", "--jsn", "a.h5"], "simreel inspect: error: unrecognized arguments: --jsn (see simreel inspect "
                                   "--help)"),  # no file; was said by `simreel`, pointing at its own --help
    (["replay", "a.h5", "--atol", "-1.5"], "simreel replay: error: argument --atol: '-1.5': a tolerance must be a "
                                           "finite number >= 0 (see simreel replay --help)"),  # a number
    (["--jsn"], "simreel: error: unrecognized arguments: --jsn (see simreel --help)"),
], ids=["positional", "second-positional", "option-value", "typo-no-hint", "number-no-hint", "no-command"])
def test_a_file_name_that_begins_with_a_dash_is_named_with_how_to_pass_it(capsys, argv, message):
    """argparse takes `-x.h5` for an option, and its message alone ("the following arguments are required") misleads."""
    assert _run(capsys, argv) == (2, message + "\n")


@pytest.mark.parametrize(("argv", "said"), [
    (["replay", "a.h5", "--episodes", "0", "--episodes", "1"], "--episodes: given twice ('0', then '1')"),
    (["filter", "a.h5", "-o", "b.h5", "--episodes", "0", "--episodes=1"], "--episodes: given twice ('0', then '1')"),
    (["video", "a.h5", "--episodes", "0-3", "--episodes", "5"], "--episodes: given twice ('0-3', then '5')"),
    (["audit", "--trajectory", "a.h5", "--episodes", "0", "--episodes", "1"], "--episodes: given twice ('0', then '1')"),
    (["convert", "a.h5", "b.h5", "--obs-mode", "state", "--episodes", "0", "--episodes", "0"],
     "--episodes: given twice ('0', then '0')"),
    (["convert", "a.h5", "b.h5", "--obs-mode", "state", "--keep", "verified", "--keep", "success"],
     "--keep: given twice ('verified', then 'success')"),
    (["record", "PickCube-v1", "-o", "b.h5", "--contacts", "none", "--contacts", "auto"],
     "--contacts: given twice ('none', then 'auto')"),
], ids=["replay", "filter", "video", "audit", "convert-episodes", "convert-keep", "record-contacts"])
def test_a_list_option_given_twice_is_refused_not_cut_to_its_last_list(tmp_path, monkeypatch, capsys, argv, said):
    """Regression: `--episodes 0 --episodes 1` replayed (filtered, ...) episode 1 alone, without a word."""
    monkeypatch.chdir(tmp_path)  # without the refusal, `record` would write b.h5 here
    prog = f"simreel {argv[0]}"
    assert _run(capsys, argv) == (2, f"{prog}: error: argument {said}; give it once, with every item in one "
                                     f"comma-separated list (see {prog} --help)\n")


def test_the_command_line_itself_gives_one_line_and_exit_2():
    """The one subprocess check: what a shell sees (stderr, exit status) from `python -m simreel`."""
    done = subprocess.run([sys.executable, "-m", "simreel", "inspect", "no-such-file.h5"], capture_output=True,
                          text=True)
    assert done.returncode == 2
    assert done.stderr == "simreel inspect: error: no-such-file.h5: no such file\n"


def test_help_imports_nothing_heavy():
    """`simreel --help` stays instant because building the parser imports no simulator, file library or viewer
    (a module list, not a stopwatch: timings belong to benchmarks/)."""
    heavy = ("mani_skill", "sapien", "torch", "rerun", "h5py", "gymnasium", "mcap")
    code = (
        "import sys; from simreel.cli.main import build_parser; build_parser(); "
        f"print([m for m in {heavy!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", f"building the CLI parser imported {out.stdout.strip()}"
    assert subprocess.run([sys.executable, "-m", "simreel", "--help"], capture_output=True).returncode == 0


def test_an_internal_error_is_one_line_and_exit_3(monkeypatch, capsys):
    import simreel.cli.inspect as inspect_cmd

    def broken(args):
        raise RuntimeError("boom")

    monkeypatch.setattr(inspect_cmd, "run", broken)
    assert main(["inspect", "whatever.h5"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["simreel inspect: internal error: RuntimeError: boom (rerun with --debug for the traceback, "
                   "and please report it)"]


_BROKEN_INSPECT = (
    "import sys, simreel.cli.inspect as command\n"
    "def run(args):\n"
    "    raise RuntimeError('boom')\n"
    "command.run = run\n"
    "from simreel.cli.main import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


@pytest.mark.parametrize(
    ("argv", "status", "last_line"),
    [
        (["-m", "simreel", "{debug}", "inspect", "no-such-file.h5"], 2,
         "simreel inspect: error: no-such-file.h5: no such file"),
        (["-c", _BROKEN_INSPECT, "{debug}", "inspect", "x.h5"], 3,
         "simreel inspect: internal error: RuntimeError: boom ({how})"),
    ],
    ids=["bad-input", "internal-error"],
)
def test_debug_adds_the_traceback_and_keeps_the_exit_status(argv, status, last_line):
    """What a shell sees: `--debug` prints the traceback before the same one line, with the same exit status."""
    runs = {}
    for debug in (False, True):
        args = [a for a in argv if a != "{debug}" or debug]
        runs[debug] = subprocess.run([sys.executable, *[a.replace("{debug}", "--debug") for a in args]],
                                     capture_output=True, text=True, timeout=60)
    plain, debug = runs[False], runs[True]
    assert plain.returncode == debug.returncode == status, debug.stderr
    assert plain.stderr.splitlines() == [last_line.format(how="rerun with --debug for the traceback, and please "
                                                             "report it")]
    lines = debug.stderr.splitlines()
    assert lines[0] == "Traceback (most recent call last):" and len(lines) > 3
    assert lines[-1] == last_line.format(how="please report it")


@pytest.mark.parametrize(("sig", "status", "line"), [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                                      (signal.SIGINT, 130, "interrupted")], ids=["SIGTERM", "SIGINT"])
def test_sigterm_stops_a_recording_as_cleanly_as_ctrl_c(tmp_path, sig, status, line):
    """Regression: SIGTERM killed the recorder with no clean-up, so its MCAP file needed `recover`."""
    from support.children import RecordingChild

    from simreel.formats import open_reader

    out = tmp_path / "rec.mcap"
    with RecordingChild("record", "PickCube-v1", "-o", str(out), "-n", "1000", "--max-steps", "10", "-q",
                        cli=True) as child:
        deadline = time.monotonic() + 180
        while not (out.exists() and b"simreel.episode.1" in out.read_bytes()):  # two episodes committed
            assert child.proc.poll() is None and time.monotonic() < deadline, child.proc.stderr.read()
            time.sleep(0.05)
        assert child.signal(sig) == status
    assert child.stderr.splitlines()[-1] == f"simreel record: {line}"
    with open_reader(out) as r:  # a complete file: summary and footer written
        assert len(r.episodes) >= 2 and r.unfinished == []
        for m in r.episodes:
            episode = r.read_episode(m.index)
            assert 1 <= episode.length <= 10
            ended = bool(episode.terminated[-1] or episode.truncated[-1])
            cut = f"cut short: {'SIGTERM' if sig == signal.SIGTERM else 'Ctrl-C (SIGINT)'} stopped the recording"
            assert m.notes == ([] if ended else [f"{cut} before this episode ended"])  # only one the stop cut
