"""simreel: record, replay-and-verify, audit and view ManiSkill 3 trajectories.

The core (`simreel`) holds the episode data model, the file formats, env building and the CLI; the rooms
`simreel.recorders`, `simreel.replay` and `simreel.viewers` build on it. Importing `simreel` is cheap: it
never imports mani_skill, sapien, torch or rerun.
"""

from __future__ import annotations

__version__ = "0.1.0"
FORMAT_VERSION = 1
"""Written into every recording; readers refuse files of a newer version."""

__all__ = ["__version__", "FORMAT_VERSION"]
