"""`merge` and `filter_recording` from Python (`simreel.datasets.dataset`): an argument or option of the wrong type is
one `UsageError` naming it and what to give, raised before any file is written (an existing OUT stays as it was);
one path is one input, never its characters; the forms the CLI and the README use stay valid."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from simreel.datasets.dataset import DatasetOptions, EpisodeCriteria, filter_recording, merge
from simreel.errors import UsageError
from simreel.formats import open_reader

STEPS = "a number of steps, an int >= 0, or None (no bound)"
OUT = "give the recording to write, a str or pathlib.Path ending in .h5 or .mcap"
VERDICT_NAMES = "exact, within_tolerance, diverged, error"


@pytest.fixture
def pickcube(record) -> Path:
    """A real recording: 2 PickCube-v1 episodes of 5 steps."""
    return record("PickCube-v1", 2, 5)


def _existing(tmp_path: Path) -> Path:
    out = tmp_path / "out.h5"
    out.write_text("an older file, to be kept")
    return out


@pytest.mark.parametrize(
    ("call", "message"),
    [
        # was: accepted as yes, and OUT was replaced
        (lambda a, out: merge([a], out, overwrite="no"), "overwrite='no': give True or False"),
        (lambda a, out: merge([a], out, overwrite=1), "overwrite=1: give True or False"),
        (lambda a, out: filter_recording(a, out, EpisodeCriteria(episodes=[0]), overwrite="no"),
         "overwrite='no': give True or False"),
        # was: refused only once the staged output was being written, naming the staging file
        (lambda a, out: merge([a], out, command=None),
         "command=None: give the command line as a string (stored in the outputs' metadata)"),
        # was: TypeError 'int' object is not callable
        (lambda a, out: merge([a], out, progress=5), "progress=5: give a function called as progress(items, what) "
                                                       "that returns the items (a progress bar), or leave it out"),
        # was: TypeError replace() should be called on dataclass instances
        (lambda a, out: merge([a], out, {"overwrite": True}), "options={'overwrite': True}: give a DatasetOptions, "
                                                               "or its fields as keywords, e.g. merge(inputs, output, "
                                                               "overwrite=True)"),
        # was: TypeError DatasetOptions.__init__() got an unexpected keyword argument 'bogus'
        (lambda a, out: merge([a], out, bogus=1), "bogus=1: give only the options DatasetOptions has: overwrite, command, progress"),
        # was: TypeError expected str, bytes or os.PathLike object, not int
        (lambda a, out: merge([a, 5], out), "inputs=[PosixPath('{a}'), 5]: give the recordings to merge, a list of "
                                            "str or pathlib.Path (or one)"),
        (lambda a, out: merge([a], None), f"output=None: {OUT}"),
        (lambda a, out: filter_recording(5, out, EpisodeCriteria(episodes=[0])),
         "path=5: give the recording to read, a str or pathlib.Path"),
        (lambda a, out: filter_recording(a, out, EpisodeCriteria(episodes=[0]), rest=5), f"rest=5: {OUT}"),
        # was: "unknown recording suffix ''"
        (lambda a, out: merge([a], ""), "an empty path names no recording (an unset shell variable?); name the "
                                        "recording to write (output)"),
        # was: AttributeError 'dict' object has no attribute 'given'
        (lambda a, out: filter_recording(a, out, {"success": True}),
         "criteria={'success': True}: give an EpisodeCriteria, e.g. EpisodeCriteria(success=True)"),
    ],
    ids=["overwrite-str", "overwrite-int", "filter-overwrite-str", "command-none", "progress-int", "options-dict",
         "unknown", "inputs-int", "output-none", "filter-path-int", "rest-int", "output-empty", "criteria-dict"],
)
def test_a_wrong_argument_is_one_usage_error_and_nothing_is_written(pickcube, tmp_path, call, message):
    out = _existing(tmp_path)
    with pytest.raises(UsageError) as refused:
        call(pickcube, out)
    assert str(refused.value) == message.replace("{a}", str(pickcube))
    assert out.read_text() == "an older file, to be kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.h5"]


@pytest.mark.parametrize(
    ("criteria", "message"),
    [
        ({"success": "no"}, "success='no': give True or False"),  # was: kept nothing ("no" is no final success)
        ({"success": 0}, "success=0: give True or False"),  # was: kept nothing, described as "no success"
        ({"min_steps": True}, f"min_steps=True: give {STEPS}"),  # was: taken as 1
        ({"min_steps": 2.5}, f"min_steps=2.5: give {STEPS}"),  # was: accepted
        ({"max_steps": math.nan}, f"max_steps=nan: give {STEPS}"),  # was: "nothing matches (0 meet <= nan steps)"
        ({"min_steps": "3"}, f"min_steps='3': give {STEPS}"),  # was: TypeError '<' not supported
        ({"max_steps": -1}, "--max-steps must be >= 0, got -1"),  # as before, the CLI's words
        ({"keep_verdicts": ("exact",)},  # was: ignored, every episode the other criteria kept was written
         "keep_verdicts without verdicts: give both (the verdicts of the file's episodes, and those to keep), or "
         "neither"),
        ({"verdicts": {0: "exact"}},  # was: "nothing matches (0 meet  in )"
         "verdicts without keep_verdicts: give both (the verdicts of the file's episodes, and those to keep), or "
         "neither"),
        ({"verdicts": ["exact"], "keep_verdicts": ("exact",)},  # was: AttributeError 'list' object has no 'get'
         f"verdicts=['exact']: give a replay's verdict of each episode as a dict of episode indices and verdicts "
         f"({VERDICT_NAMES}), e.g. {{0: \"exact\"}} (simreel.datasets.dataset.report_verdicts reads them from a "
         "replay report)"),
        ({"verdicts": {0: "exact"}, "keep_verdicts": ("verified",)},  # was: "nothing matches"
         f"keep_verdicts=('verified',): give the verdicts to keep as a tuple of any of {VERDICT_NAMES}, e.g. "
         "(\"exact\", \"within_tolerance\")"),
        ({"verdicts": {0: "exact"}, "keep_verdicts": ("exact",), "report": None},  # was: TypeError in describe()
         "report=None: give where the verdicts came from as a string (the replay report's path)"),
    ],
    ids=["success-str", "success-int", "min_steps-bool", "min_steps-float", "max_steps-nan", "min_steps-str",
         "max_steps-negative", "keep-without-verdicts", "verdicts-without-keep", "verdicts-list", "keep-unknown",
         "report-none"],
)
def test_a_criterion_of_the_wrong_type_is_one_usage_error_when_the_criteria_are_built(criteria, message):
    with pytest.raises(UsageError) as refused:
        EpisodeCriteria(**criteria)
    assert str(refused.value) == message


def test_one_path_is_one_input_and_any_iterable_of_paths_is_the_inputs(pickcube, tmp_path):
    """Regression: merge("a.h5", OUT) read the files "a", ".", "h", "5"; merge(Path) was TypeError 'PosixPath' object
    is not iterable; a generator was consumed by the duplicate check and then IndexError."""
    one = merge(pickcube, tmp_path / "one.h5")
    assert [n for _, _, n in one.inputs] == [2]
    two = merge((p for p in [str(pickcube), tmp_path / "one.h5"]), tmp_path / "two.mcap")
    assert [n for _, _, n in two.inputs] == [2, 2]
    with open_reader(tmp_path / "two.mcap") as reader:
        assert len(reader.episodes) == 4


def test_the_forms_the_cli_and_python_use_stay_valid(pickcube, tmp_path):
    """numpy ints and bools are counts and flags; one verdict given as a string is that verdict, not its
    characters; a progress of None is none."""
    import numpy as np

    criteria = EpisodeCriteria(success=np.bool_(False), min_steps=np.int64(1), verdicts={np.int64(0): "exact"},
                               keep_verdicts="exact", report=str(tmp_path / "r.json"))
    assert (criteria.min_steps, criteria.keep_verdicts, criteria.verdicts) == (1, ("exact",), {0: "exact"})
    assert type(criteria.min_steps) is int
    report = filter_recording(pickcube, tmp_path / "kept.h5", criteria, DatasetOptions(command="x"),
                              overwrite=np.bool_(False), progress=None)  # None: no progress bar
    assert report.outputs[0].episodes == 1 and report.criteria == "no success; >= 1 steps; exact in r.json"
