"""`ConvertOptions` from Python: a value of the wrong type is one `UsageError` naming the option and what to give,
raised when the options are built (before any env or file); a tolerance that is no finite number >= 0 is refused
however the tolerances are built; the forms the CLI and the README use stay valid."""

from __future__ import annotations

import math

import pytest

from simreel.errors import UsageError
from simreel.model.components import Tolerances
from simreel.replay.convert.convert import ConvertOptions
from simreel.replay.convert.tracking import tracking_tolerances

CAMERA = "give (width, height) of the cameras in pixels, two ints >= 1, e.g. (128, 128), or None (the task's)"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"overwrite": "no"}, "overwrite='no': give True or False"),  # was: accepted, as yes
        ({"workers": "2"}, "workers='2': give the number of processes converting episodes, an int >= 1"),  # was:
        # accepted, then TypeError '<' not supported between 'str' and 'int' in check()
        ({"count": "3"}, "count='3': give the number of episodes to convert, an int >= 1, or None (all of them)"),
        ({"block_rows": True}, "block_rows=True: give the number of steps converted at a time, an int >= 1, or None "
                               "(the reader's)"),  # was: accepted, as 1
        ({"keep": 5}, 'keep=5: give the episodes to write as a tuple of any of verified, success, not_truncated, all, '
                      'e.g. ("verified",)'),  # was: TypeError 'int' object is not iterable
        ({"camera_size": "128x128"}, f"camera_size='128x128': {CAMERA}"),  # was: a tuple of 7 characters
        ({"camera_size": (1.5, 2)}, f"camera_size=(1.5, 2): {CAMERA}"),  # was: accepted
        ({"obs_mode": 5}, 'obs_mode=5: give an observation mode as a string, e.g. "rgb", or None (the recorded '
                          'one)'),
        ({"control_mode": 5}, 'control_mode=5: give a control mode as a string, e.g. "pd_ee_delta_pose", or None '
                              '(the recorded one)'),
        ({"command": None}, "command=None: give the command line as a string (kept in the output's metadata)"),
        ({"imports": 5}, 'imports=5: give the .py files or modules that register the task, as a tuple of strings, '
                         'e.g. ("my_tasks.py",)'),
        ({"group_tolerances": [1]}, 'group_tolerances=[1]: give a dict of tracking tolerance groups and numbers, '
                                    'e.g. {"ee_pos": 1e-3}'),
        ({"converter": 5}, "converter=5: give a factory called as simreel.replay.convert.control.converter_for is, or None"),
    ],
    ids=["overwrite-str", "workers-str", "count-str", "block_rows-bool", "keep-int", "camera_size-str",
         "camera_size-float", "obs_mode-int", "control_mode-int", "command-none", "imports-int",
         "group_tolerances-list", "converter-int"],
)
def test_an_option_of_the_wrong_type_is_one_usage_error_when_the_options_are_built(options, message):
    with pytest.raises(UsageError) as refused:
        ConvertOptions(**{"obs_mode": "state", **options})
    assert str(refused.value) == message


@pytest.mark.parametrize(
    ("options", "overrides", "message"),
    [
        ({"obs_mode": "rgb"}, {}, "options={'obs_mode': 'rgb'}: give a ConvertOptions, or its fields as keywords, "
                                  'e.g. ConversionRun(src, dst, obs_mode="rgb")'),  # was: TypeError from replace()
        (None, {"obs_mode": "rgb", "camera": 5}, "camera=5: give only the options ConvertOptions has: obs_mode, "
                                                 "control_mode, camera_size, shader, episodes, count, keep, "
                                                 "group_tolerances, workers, imports, trust_recorded_imports, sim_backend, overwrite, command, "
                                                 "converter, block_rows"),  # was: TypeError naming its __init__
    ],
    ids=["options-dict", "unknown"],
)
def test_a_conversion_of_options_of_the_wrong_type_or_no_option_is_one_usage_error(tmp_path, options, overrides,
                                                                                    message):
    from simreel.replay.convert.run import ConversionRun

    with pytest.raises(UsageError) as refused:
        ConversionRun(tmp_path / "in.h5", tmp_path / "out.h5", options, **overrides)
    assert str(refused.value) == message
    assert list(tmp_path.iterdir()) == []


def test_the_forms_the_cli_and_python_use_stay_valid_and_one_string_is_one_name():
    """Regression: `imports="tasks.py"` and `keep="success"` became one spec (name) per character."""
    import numpy as np

    opts = ConvertOptions(obs_mode="state", imports="tasks.py", keep="success", workers=np.int64(2), count=3,
                          camera_size=[64, 48], episodes="0,3-5", group_tolerances={"ee_pos": 1e-3})
    assert (opts.imports, opts.keep, opts.workers, opts.camera_size) == (("tasks.py",), ("success",), 2, (64, 48))
    assert type(opts.workers) is int and list(opts.episodes) == [0, 3, 4, 5]
    opts.check()
    with pytest.raises(UsageError, match="--workers and --count must be >= 1"):  # values stay check()'s, CLI-worded
        ConvertOptions(obs_mode="state", workers=0).check()


@pytest.mark.parametrize("bad", [math.nan, -1.0, math.inf, "x", True])
def test_a_tracking_tolerance_that_is_no_finite_number_at_least_zero_is_refused(bad):
    """Regression: `group_tolerances={"ee_pos": nan}` from Python was taken as it was, and NaN passes no comparison the
    way a tolerance must (the CLI's --tol refused it; `tracking_tolerances` did not)."""
    with pytest.raises(UsageError, match="tracking tolerance ee_pos"):
        tracking_tolerances({"ee_pos": bad})
    with pytest.raises(ValueError, match="tolerance pos"):
        Tolerances({"pos": bad})
    assert tracking_tolerances({"ee_pos": 0}).values["ee_pos"] == 0.0
