"""simreel: record, replay-and-verify, audit and view ManiSkill 3 trajectories.

The core (`simreel`) holds the episode data model (`episode`, `state_tree`, `compare`, `errors`) and four
packages: `sim` (building and reading live envs), `formats` (recording files), `authoring` (helpers for task
authors) and `cli`. The rooms `simreel.recorders`, `simreel.replay` and `simreel.viewers` build on it and
never import each other. Importing `simreel` is cheap: it never imports mani_skill, sapien, torch or rerun.

Importing it does one thing besides: it points the Vulkan loader at the software driver that `make setup`
fetched (`simreel.sim.render_device.configure_vulkan`), when the machine has no NVIDIA GPU and the user chose
no driver, so that a user's own ``gym.make`` after ``import simreel`` finds a render device.
"""

from __future__ import annotations

import sys

__version__ = "0.1.0"
FORMAT_VERSION = 1
"""Written into every recording; readers refuse files of a newer version."""

__all__ = ["__version__", "FORMAT_VERSION"]


def _install_documented_aliases() -> None:
    """`simreel.custom_state` and `simreel.heterogeneous`, the documented import paths of the task-author
    helpers, are the modules under `simreel.authoring` (both are light: they import nothing heavy)."""
    from simreel.authoring import custom_state, heterogeneous

    for name, module in (("custom_state", custom_state), ("heterogeneous", heterogeneous)):
        sys.modules[f"{__name__}.{name}"] = module
        globals()[name] = module


_install_documented_aliases()

from simreel.sim.render_device import configure_vulkan  # noqa: E402  (after the aliases: no cycle)

configure_vulkan()
