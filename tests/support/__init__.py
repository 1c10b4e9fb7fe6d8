"""Helpers the tests share (importable as `support`: pytest puts tests/ on sys.path, see pyproject.toml).

- `mcap_samples`: synthetic recordings (arrays a float formatter would damage), no env
- `rrd`: read a Rerun .rrd back with rerun-sdk's own reader
- `viewer_data`: a small real PickCube recording and replay-like variants of it
- `mcap_kill_child`, `record_until_killed`: child processes the kill -9 tests start and kill
- `processes`: simreel as a subprocess: its command line, an environment without a display, free ports
- `paused_copy`: `simreel merge` or `filter` paused mid-copy, for Ctrl-C and concurrent-output tests
- `unreadable`: paths that name no readable file: a symbolic link loop, a file this user may not read
"""
