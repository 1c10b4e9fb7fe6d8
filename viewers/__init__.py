"""simreel.viewers: the viewing room — a recording (and optionally its replay) as a Rerun session.

    from simreel.viewers import build_session

    with build_session("run.h5", episode=0, compare="replayed.h5") as session:
        session.save("run.rrd")          # or session.spawn() / session.serve()

Entity paths and timelines are in `simreel.viewers.paths`. rerun is imported by the modules of this
package, never by the core (`import simreel` stays free of rerun and mani_skill).
"""

from __future__ import annotations

from typing import Any

__all__ = ["build_session", "rebuild_env", "ViewOptions", "ViewSession", "ViewError"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from simreel.viewers import session

        return getattr(session, name)
    raise AttributeError(f"module 'simreel.viewers' has no attribute {name!r}")
