"""Options shared by every command that builds an env, and the helpers that apply them."""

from __future__ import annotations

import argparse
import json
from typing import Any

from simreel.errors import UsageError

__all__ = ["add_env_options", "add_import_option", "apply_imports", "parse_json_kwargs", "parse_index_ranges"]


def add_import_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--import",
        dest="imports",
        action="append",
        default=[],
        metavar="MODULE_OR_FILE",
        help="import user code (a module or a .py file) that registers tasks or policies; repeatable",
    )


def add_env_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--obs-mode", default="state", help="ManiSkill obs_mode (default: state)")
    p.add_argument("--control-mode", default=None, help="ManiSkill control_mode (default: the task's)")
    p.add_argument("--reward-mode", default=None, help="ManiSkill reward_mode (default: the task's)")
    p.add_argument("--sim-backend", default="auto", help="physx_cpu, physx_cuda or auto (default)")
    p.add_argument("--render-backend", default="auto", help="gpu, cpu, none or auto (default: detected)")
    p.add_argument("--num-envs", type=int, default=1, help="parallel envs (>1 needs the GPU sim)")
    p.add_argument("--env-kwargs", type=parse_json_kwargs, default={}, metavar="JSON",
                   help='extra gym.make kwargs as a JSON object, e.g. \'{"robot_uids": "panda"}\'')
    add_import_option(p)


def apply_imports(specs: list[str]) -> None:
    from simreel.envs import import_user_code

    for spec in specs:
        import_user_code(spec)


def parse_json_kwargs(text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise argparse.ArgumentTypeError(f"not valid JSON ({e.msg})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError("expected a JSON object")
    return value


def parse_index_ranges(text: str) -> list[int]:
    """`"0,3-7"` → [0, 3, 4, 5, 6, 7]."""
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if hi < lo:
                    raise ValueError
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise UsageError(f"bad episode list {text!r}: expected e.g. 0,3-7") from None
    return out
