"""simreel: record, replay-and-verify, audit and view ManiSkill 3 trajectories.

The core, in layers that import only downwards (checked by tests/test_architecture.py):

- `errors`; `options` (each command option declared once, and the checks of values a caller gives)
- `model`: the episode data model (metadata, the field table, blocks of rows, episodes, state trees, components)
- `io`: signals, durable writes, the output rule, staging, locks, paths
- `formats`: the HDF5, MCAP and ManiSkill formats behind one reader/writer registry;
  `verdicts`: what a replay is judged by; `authoring`: helpers for task authors
- `tasks`: simreel's example tasks; `sim`: building and reading live envs
- `datasets`: operations on whole recordings (copy, recover, merge, filter, inputs)
- the rooms `simreel.recorders`, `simreel.replay`, `simreel.viewers`, which never import each other; `cli`

Importing `simreel` does nothing besides defining the two constants below: it imports no simulator or viewer and
changes no environment variable (the recorder room and `simreel.sim.make.make_env` prepare the machine for
ManiSkill when they are used).
"""

__version__ = "0.1.0"
FORMAT_VERSION = 1
"""Written into every recording; readers refuse files of a newer version."""

__all__ = ["__version__", "FORMAT_VERSION"]
