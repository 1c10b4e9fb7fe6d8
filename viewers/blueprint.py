"""The layout a session opens with: the 3D scene, time series in tabs, the events log, camera images."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import rerun.blueprint as rrb

from simreel.viewers.paths import CAMERAS, COMPARED, CONTACTS, EVENTS, PLOTS, STEP, WORLD

__all__ = ["Layout", "session_blueprint"]


@dataclass(frozen=True)
class Layout:
    """What the session holds, as far as the layout cares."""

    compare: bool = False
    cameras: tuple[str, ...] = ()
    """Entity paths of camera image streams (``cameras/<camera>/rgb``)."""
    plot_groups: tuple[str, ...] = ("reward", "success", "info", "qpos", "contacts")
    """Which ``plots/<group>`` exist."""
    eye: tuple[float, float, float] | None = None
    look_target: tuple[float, float, float] | None = None
    focus: tuple[int, int] | None = None
    """A step range to select on the time panel (around the first divergence)."""
    title: str = "scene"


def _plots_tab(name: str, contents: Sequence[str]) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=name, origin=PLOTS, contents=list(contents),
                              plot_legend=rrb.PlotLegend(corner="LeftTop"))


def session_blueprint(layout: Layout) -> rrb.Blueprint:
    """A pure function of `layout`: 3D view left, plot tabs + events right, camera images under the 3D view."""
    contents = [f"{WORLD}/**", f"{CONTACTS}/**"]
    if layout.compare:
        contents.append(f"{COMPARED}/**")
    eye = None
    if layout.eye is not None:
        eye = rrb.EyeControls3D(position=layout.eye, look_target=layout.look_target, eye_up=(0.0, 0.0, 1.0))
    scene = rrb.Spatial3DView(name=layout.title, origin="/", contents=contents, eye_controls=eye)
    left: rrb.Container | rrb.View = scene
    if layout.cameras:
        cams = [rrb.Spatial2DView(name=path[len(CAMERAS) + 1 :], origin=path) for path in layout.cameras]
        left = rrb.Vertical(scene, rrb.Horizontal(*cams), row_shares=[3, 1])

    groups = set(layout.plot_groups)
    tabs = []
    if layout.compare:
        tabs.append(_plots_tab("state error vs tolerance", ["$origin/error/env_states/**"]))
        tabs.append(_plots_tab("other errors", ["$origin/error/**", "- $origin/error/env_states/**"]))
    task = [f"$origin/{g}/**" for g in ("reward", "success", "info") if g in groups] or ["$origin/reward/**"]
    tabs.append(_plots_tab("reward & success", task))
    if "qpos" in groups:
        tabs.append(_plots_tab("joint positions", ["$origin/qpos/**"]))
    if "contacts" in groups:
        tabs.append(_plots_tab("contact forces (N)", ["$origin/contacts/**"]))
    right = rrb.Vertical(rrb.Tabs(*tabs, active_tab=0), rrb.TextLogView(name="events", origin=EVENTS),
                         row_shares=[3, 1])
    selection = None
    if layout.focus is not None:
        from rerun.blueprint.components import AbsoluteTimeRange

        selection = AbsoluteTimeRange(min=layout.focus[0], max=layout.focus[1])
    time_panel = rrb.TimePanel(timeline=STEP, state="expanded", time_selection=selection)
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        time_panel,
    )
