"""`ReplayOptions` and `ReplayRun` from Python: a value of the wrong type is one `UsageError` naming the option and
what to give, raised when the object is built (before any env or file); the forms the README and the CLI use stay
valid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simreel.errors import UsageError
from simreel.model.selection import EpisodeSelection
from simreel.replay import ReplayOptions, ReplayRun, verify_recording

EPISODES = 'give episode indices, ints >= 0 (e.g. [0, 3]), their text as --episodes takes it ("0,3-7"), or None (all)'
RESYNC = "give the number of actions between two restores of the recorded state, an int >= 1, or None (never restore)"
WORKERS = "give the number of processes (Ray workers with ray) working on the episodes, an int >= 1"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"resync": "3"}, f"resync='3': {RESYNC}"),  # was: TypeError '<' not supported between 'str' and 'int'
        ({"resync": True}, f"resync=True: {RESYNC}"),  # was: accepted, as a resync every step
        ({"resync": 1.5}, f"resync=1.5: {RESYNC}"),  # was: accepted
        ({"workers": "2"}, f"workers='2': {WORKERS}"),  # was: TypeError
        ({"workers": 1.5}, f"workers=1.5: {WORKERS}"),  # was: accepted
        ({"atol": "x"}, "atol 'x' is not a number"),  # was: TypeError must be real number, not str
        ({"atol": True}, "atol True is not a number"),  # was: accepted as 1.0
        ({"group_tolerances": [1]}, 'group_tolerances=[1]: give a dict of tolerance groups and numbers, e.g. '
                                    '{"contact": 5.0}'),  # was: TypeError cannot convert dictionary update sequence
        ({"episodes": 5}, f"episodes=5: not a list of indices; {EPISODES}"),  # was: TypeError 'int' is not iterable
        ({"episodes": "x"}, f"episodes='x': 'x' is not a number of digits; {EPISODES}"),  # was: ValueError
        ({"episodes": [0, 1.5]}, f"episodes=[0, 1.5]: 1.5 is not a whole number; {EPISODES}"),  # was: TypeError
        ({"episodes": [-1]}, f"episodes=[-1]: -1 is negative; {EPISODES}"),  # was: accepted, naming no episode
        ({"imports": 5}, 'imports=5: give the .py files or modules that register the task, as a tuple of strings, '
                         'e.g. ("my_tasks.py",)'),  # was: TypeError 'int' object is not iterable
        ({"overwrite": "no"}, "overwrite='no': give True or False"),  # was: accepted, as yes
        ({"resume": 1}, "resume=1: give True or False"),
        ({"ship": "no"}, "ship='no': give True or False"),  # was: accepted, as yes
        ({"ship": True}, "--ship works with --ray only: it sends the episodes to the Ray actors"),  # was: ignored
        ({"output": 5}, "output=5: give the file to write the replayed episodes to, a str or pathlib.Path ending in "
                        ".h5 or .mcap, or None"),  # was: accepted as a file named 5
        ({"report": 5}, "report=5: give the report to write, a str or pathlib.Path (REPORT.json), or None"),
        ({"report": ""}, "an empty path names no file (an unset shell variable?); give the report to write, a str or "
                         "pathlib.Path (REPORT.json), or None"),  # was: taken for None, and no report was written
        ({"output": ""}, "an empty path names no file (an unset shell variable?); give the file to write the replayed "
                         "episodes to, a str or pathlib.Path ending in .h5 or .mcap, or None"),
        ({"obs_mode": 5}, 'obs_mode=5: give an observation mode as a string, e.g. "rgb", or None (the recorded '
                          'one)'),
        ({"sim_backend": 5}, 'sim_backend=5: give a sim backend as a string, e.g. "physx_cpu", or None (the '
                             'recorded one)'),
        ({"ray": 5}, 'ray=5: give "local", "auto" or a cluster address ("ray://host:10001", "host:6379") as a '
                     'string, or None (no Ray)'),  # was: AttributeError, only at execute()
        ({"command": 5}, "command=5: give the command line as a string (kept in the output's metadata)"),
    ],
    ids=["resync-str", "resync-bool", "resync-float", "workers-str", "workers-float", "atol-str", "atol-bool",
         "group_tolerances-list", "episodes-int", "episodes-bad-text", "episodes-float", "episodes-negative",
         "imports-int", "overwrite-str", "resume-int", "ship-str", "ship-without-ray", "output-int", "report-int",
         "report-empty", "output-empty",
         "obs_mode-int", "sim_backend-int", "ray-int", "command-int"],
)
def test_an_option_of_the_wrong_type_is_one_usage_error_when_the_options_are_built(tmp_path, monkeypatch, options,
                                                                                    message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UsageError) as refused:
        ReplayOptions(**options)
    assert str(refused.value) == message
    with pytest.raises(UsageError) as refused:  # the same through ReplayRun's keywords, before any file is read
        ReplayRun(str(tmp_path / "missing.h5"), **options)
    assert str(refused.value) == message
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("inputs", "options", "message"),
    [
        (5, None, "inputs=5: give the recordings to replay (files, folders or glob patterns) as a str or pathlib.Path, "
                  "or a list of them"),  # was: TypeError 'int' object is not iterable
        (["a.h5", 5], None, "inputs=['a.h5', 5]: give the recordings to replay (files, folders or glob patterns) as a "
                            "str or pathlib.Path, or a list of them"),  # was: taken for a file named 5
        ("a.h5", {"mode": "step"}, "options={'mode': 'step'}: give a ReplayOptions, or its fields as keywords, e.g. "
                                   'ReplayRun(paths, mode="step")'),  # was: TypeError from dataclasses.replace
    ],
    ids=["inputs-int", "inputs-list-with-int", "options-dict"],
)
def test_a_replay_run_of_inputs_or_options_of_the_wrong_type_is_one_usage_error(tmp_path, monkeypatch, inputs,
                                                                                 options, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UsageError) as refused:
        ReplayRun(inputs, options)
    assert str(refused.value) == message
    assert list(tmp_path.iterdir()) == []


def test_a_keyword_that_is_no_option_is_one_usage_error_naming_the_options(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UsageError) as refused:  # was: TypeError ReplayOptions.__init__() got an unexpected keyword
        ReplayRun("a.h5", atoll=0.1)
    assert str(refused.value) == ("atoll=0.1: give only the options ReplayOptions has: mode, resync, episodes, atol, "
                                  "group_tolerances, output, overwrite, obs_mode, workers, imports, trust_recorded_imports, sim_backend, "
                                  "command, report, resume, ray, ship")
    assert list(tmp_path.iterdir()) == []


def test_resuming_a_report_that_is_no_path_is_one_usage_error(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UsageError) as refused:  # was: TypeError expected str, bytes or os.PathLike object, not int
        ReplayRun.resume(5)
    assert str(refused.value) == "report=5: give the report to continue, a str or pathlib.Path (REPORT.json)"
    assert list(tmp_path.iterdir()) == []


def test_the_documented_forms_of_the_options_stay_valid(record, tmp_path):
    """Episodes as the CLI's text, as indices (numpy's too) or a selection; counts as numpy ints; tolerances as ints;
    one import as a string; paths as `pathlib.Path`: each is taken, in one form, and a run with them verifies."""
    for episodes in ("0,3-7", [0, 3, 4, 5, 6, 7], np.arange(8)[[0, 3, 4, 5, 6, 7]], EpisodeSelection.parse("0,3-7")):
        assert list(ReplayOptions(episodes=episodes).episodes) == [0, 3, 4, 5, 6, 7]
    options = ReplayOptions(resync=np.int64(5), workers=np.int64(1), atol=1, group_tolerances={"contact": 2},
                            imports="simreel.tasks", report=tmp_path / "r.json", overwrite=np.bool_(False))
    assert (options.resync, options.workers, options.atol, options.group_tolerances) == (5, 1, 1.0, {"contact": 2.0})
    assert options.imports == ("simreel.tasks",) and options.report == str(tmp_path / "r.json")

    path = record("PickCube-v1", 2, 20)
    report = verify_recording(Path(path), options, episodes=[np.int64(1)])
    assert [e.index for e in report.episodes] == [1] and report.ok, report.summary()
    assert (tmp_path / "r.json").is_file()
