"""`ConvertOptions`: what a verified conversion converts, how it judges and what it writes — what `simreel convert`
takes with ``--obs-mode``/``--control-mode``, each option declared once (`simreel.options.declare`): the command's
flags, their help and the Python checks come from these fields. Light to import: the CLI builds its parser from it."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from simreel.errors import UsageError
from simreel.model.selection import EpisodeSelection, parse_index_ranges
from simreel.options.checks import (
    flag,
    function,
    mapping,
    parse_size,
    text,
    text_tuple,
    whole,
    whole_number_pair,
)
from simreel.options.declare import GivenOnce, check_options, documented, option
from simreel.sim.user_code import IMPORTS, TRUST_IMPORTS, import_specs
from simreel.verdicts.options import TOL, parse_group_tolerance

__all__ = ["ConvertOptions", "KEEP", "TRACKING_GROUPS"]

KEEP = ("verified", "success", "not_truncated", "all")
"""What `ConvertOptions.keep` may ask of an episode for it to be written: ``verified`` always (the default), with
``success`` and/or ``not_truncated`` too; ``all`` alone writes every converted episode, verified or not."""
TRACKING_GROUPS = ("cmd_pos", "cmd_rot", "ee_pos", "ee_rot", "obj_pos", "obj_rot", "obj_qpos", "success")
"""The tracking tolerance groups of a control-mode conversion (`simreel.replay.convert.tracking`)."""


def _keep_text(text: str) -> tuple[str, ...]:
    """``--keep verified,success``: the names, each one of `KEEP`."""
    wanted = tuple(w.strip().replace("-", "_") for w in text.split(",") if w.strip())
    unknown = [w for w in wanted if w not in KEEP]
    if unknown or not wanted:
        raise argparse.ArgumentTypeError(f"expected any of {', '.join(KEEP)}, got {text!r}")
    return wanted


def _tracking_tolerance(text: str) -> tuple[str, float]:
    return parse_group_tolerance(text, TRACKING_GROUPS)


def _keep(name: str, keep: Any) -> tuple[str, ...]:
    """The `keep` option as a tuple of `KEEP` names: one string is one name (not one per character); anything but
    strings is `UsageError` (names it does not know are `ConvertOptions.check`'s)."""
    return text_tuple(name, keep, f"the episodes to write as a tuple of any of {', '.join(KEEP)}, e.g. "
                                  '("verified",)')


def _camera_size(name: str, value: Any) -> tuple[int, int] | None:
    what = "(width, height) of the cameras in pixels, two ints >= 1, e.g. (128, 128), or None (the task's)"
    return None if value is None else whole_number_pair(name, value, what)


@documented
@dataclass(frozen=True)
class ConvertOptions:
    """What `convert_recording` converts, how it judges and what it writes; `check` refuses what cannot work whatever
    the file. `converter` (Python only) is the factory of the action converter, called as
    `simreel.replay.convert.control.converter_for` is (``(source_mode, target_mode, unwrapped, source_controller) ->
    ActionConverter``): bring your own for a robot or mode pair simreel does not convert, and it is verified the
    same way. Picklable for workers."""

    obs_mode: str | None = option(
        None, help="observation mode of OUT: state, state_dict, rgb, rgbd, depth, pointcloud, sensor_data, ... "
                   "(cameras render on a GPU or on lavapipe)",
        check=text('an observation mode as a string, e.g. "rgb", or None (the recorded one)', optional=True))
    control_mode: str | None = option(
        None, help="convert the actions to this control mode: from pd_joint_pos to pd_joint_delta_pos, "
                   "pd_joint_target_delta_pos, pd_joint_vel, pd_ee_delta_pos, pd_ee_delta_pose, pd_ee_target_delta_pos "
                   "or pd_ee_target_delta_pose; from pd_joint_delta_pos to pd_joint_pos",
        check=text('a control mode as a string, e.g. "pd_ee_delta_pose", or None (the recorded one)', optional=True))
    camera_size: tuple[int, int] | None = option(None, metavar="WxH", parse=parse_size,
                                                 help="size of every sensor camera", check=_camera_size)
    shader: str | None = option(
        None, help="ManiSkill shader of every camera (default, rt, rt-fast, ...)",
        check=text('a ManiSkill shader_dir as a string, e.g. "rt", or None (the default)', optional=True))
    episodes: EpisodeSelection | Sequence[int] | None = option(
        None, metavar="LIST", action=GivenOnce, help="episodes to convert, e.g. 0,3-7 (default: all)",
        from_cli=lambda text: None if text is None else parse_index_ranges(text),
        check=lambda name, value: EpisodeSelection.of(value))  # ranges, whatever the numbers
    count: int | None = option(
        None, metavar="N", parse=int,
        help="convert only the first N of those episodes; --keep then chooses which of them are written (N "
             "converted, at most N written)",
        check=whole("the number of episodes to convert, an int >= 1, or None (all of them)", optional=True))
    keep: tuple[str, ...] = option(
        ("verified",), metavar="WHAT", parse=_keep_text, action=GivenOnce, check=_keep,
        help="which converted episodes are written: verified (their check passed; the default), and also (comma-"
             "separated) success (at their last step), not_truncated (they did not end at the time limit); or all "
             "(every converted episode, verified or not)")
    group_tolerances: Mapping[str, float] = option(
        default_factory=dict, spec=TOL, parse=_tracking_tolerance,
        help="tracking tolerance of a control-mode conversion, repeatable; groups: cmd_pos (m), cmd_rot (rad), ee_pos "
             "(m), ee_rot (rad), obj_pos (m), obj_rot (rad), obj_qpos, success (steps)",
        check=mapping('a dict of tracking tolerance groups and numbers, e.g. {"ee_pos": 1e-3}'))
    workers: int = option(1, metavar="N", parse=int, help="parallel processes (default 1)",
                          check=whole("the number of processes converting episodes, an int >= 1"))
    imports: tuple[str, ...] = option(default_factory=tuple, spec=IMPORTS,
                                      check=lambda name, value: import_specs(value))  # as given: a worker reads them
    trust_recorded_imports: bool = option(False, spec=TRUST_IMPORTS)
    sim_backend: str | None = option(
        None, help="convert on this sim backend (physx_cpu for a GPU recording)",
        check=text('a sim backend as a string, e.g. "physx_cpu", or None (the recorded one)', optional=True))
    overwrite: bool = option(False, action="store_true", help="replace OUT (and --report) if they exist",
                             check=flag())
    command: str = option("", cli=False, help="the command line, kept in the output's metadata",
                          check=text("the command line as a string (kept in the output's metadata)"))
    converter: Callable[..., Any] | None = option(
        None, cli=False,
        check=function("a factory called as simreel.replay.convert.control.converter_for is, or None"),
        help="the factory of the action converter (see above)")
    block_rows: int | None = option(
        None, cli=False, help="steps read, converted, checked and written at a time (None: the input reader's "
                              "`simreel.formats.base.block_rows`)",
        check=whole("the number of steps converted at a time, an int >= 1, or None (the reader's)", optional=True))

    def __post_init__(self) -> None:
        """Check every option's type (`check_options`), so that a wrong one is a `UsageError` here, naming it and what
        to give, not a raw error once the conversion runs or a value taken for another (``overwrite="no"`` as yes,
        ``imports="x.py"`` as one spec per character); put them in one form: episodes as an `EpisodeSelection`,
        counts as ints, sequences as tuples. Their values (counts >= 1, known `keep` names) are `check`'s, whose
        messages name the CLI's options."""
        check_options(self)

    def check(self) -> None:
        """`UsageError` for options that cannot work whatever the file: nothing to convert, bad numbers."""
        if self.obs_mode is None and self.control_mode is None:
            raise UsageError("nothing to convert: give an observation mode (--obs-mode) and/or a control mode "
                             "(--control-mode); `simreel convert IN OUT` alone copies a recording between formats")
        unknown = sorted(set(self.keep) - set(KEEP))
        if unknown:
            raise UsageError(f"--keep {','.join(unknown)}: expected any of {', '.join(KEEP)}")
        if "all" in self.keep and len(set(self.keep)) > 1:
            raise UsageError(f"--keep {','.join(self.keep)}: all writes every converted episode; give it alone")
        if self.workers < 1 or (self.count is not None and self.count < 1):
            raise UsageError(f"--workers and --count must be >= 1 (got {self.workers}, {self.count})")
        if self.block_rows is not None and self.block_rows < 1:
            raise UsageError(f"block_rows must be >= 1, got {self.block_rows}")
        if self.camera_size is not None and (len(self.camera_size) != 2 or min(self.camera_size) < 1):
            raise UsageError(f"--camera-size must be WIDTHxHEIGHT, got {self.camera_size}")

    def env_kwargs(self) -> dict[str, Any]:
        """The ``gym.make`` arguments the camera options add."""
        out: dict[str, Any] = {}
        if self.camera_size is not None:
            out["sensor_configs"] = {"width": int(self.camera_size[0]), "height": int(self.camera_size[1])}
        if self.shader is not None:
            out["shader_dir"] = self.shader
        return out
