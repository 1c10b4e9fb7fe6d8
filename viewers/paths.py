"""Entity paths and timelines of a simreel Rerun session, in one place.

- ``world/<actor>``, ``world/<articulation>/<link>``: the recorded scene; geometry static, poses on the timelines
- ``compared/<actor>``, ``compared/<articulation>/<link>``: the ghost of the episode compared (``--compare``), under
  this one name whatever that file is (a replay, a conversion, another recording); the text says which
- ``contacts/net/<body>``, ``contacts/pair/<body a>/<body b>``: contact-force arrows, only where non-zero
- ``plots/...``: reward, success, info, qpos per articulation, contact magnitudes, verification error
- ``cameras/<camera>/rgb|depth``: recorded camera observations
- ``events``: a text log of episode events (start, success, termination, first divergence)

Timelines: ``step`` counts env steps as simreel reports them (``simreel replay``: "diverged at step 143"):
step k shows the outcome of step k (0-based) — state row k + 1 of `Episode.env_states`, reward k, contacts
k, info k — and the state right after the reset is at step -1. ``sim_time`` is the simulated time since the
reset: (k + 1) × the control period, so the reset is at 0 s.
"""

from __future__ import annotations

__all__ = [
    "STEP",
    "RESET_STEP",
    "step_of_row",
    "SIM_TIME",
    "WORLD",
    "COMPARED",
    "CONTACTS",
    "PLOTS",
    "CAMERAS",
    "EVENTS",
    "body_path",
    "contact_path",
    "plot_path",
]

STEP = "step"
RESET_STEP = -1
"""The `step` of the state right after the reset (state row 0)."""
SIM_TIME = "sim_time"
WORLD = "world"
COMPARED = "compared"
CONTACTS = "contacts"
PLOTS = "plots"
CAMERAS = "cameras"
EVENTS = "events"


def step_of_row(row: int) -> int:
    """The `step` timeline value of state row `row` (row 0: after reset → -1; row k + 1: outcome of step k)."""
    return int(row) - 1


def _escaped(name: str) -> str:
    """A slash-separated simreel name as entity path parts, each escaped as Rerun requires (``a:b`` → ``a\\:b``)."""
    from rerun import escape_entity_path_part

    return "/".join(escape_entity_path_part(part) for part in name.split("/"))


def body_path(root: str, body: str) -> str:
    """``world/cube``, ``world/panda/panda_hand``: a body name (``<actor>`` / ``<articulation>/<link>``) under root."""
    return f"{root}/{_escaped(body)}"


def contact_path(kind: str, bodies: tuple[str, ...]) -> str:
    """``contacts/net/cube``, ``contacts/pair/panda/panda_leftfinger/cube``."""
    return f"{CONTACTS}/{kind}/" + "/".join(_escaped(b) for b in bodies)


def plot_path(*parts: str) -> str:
    """``plots/reward``, ``plots/error/actors/cube``: parts may themselves be slash-separated key paths."""
    return "/".join([PLOTS, *(_escaped(p) for p in parts)])
