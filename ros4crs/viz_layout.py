"""The Foxglove layout of the live view, built with foxglove-sdk's :mod:`foxglove.layouts` (the
format the Foxglove app imports: *Layout* -> *Import from file*).

:func:`live_layout` lays out what :mod:`ros4crs.visualizer_node` serves for a set of cars: a 3D
panel on ``/viz/scene`` looking down on the track (``world`` frame, orthographic, centred on the
track), the cars' estimate status over time (``/viz/<car>/status.status``), a plot of their
controller call times and laps, and the raw status messages of the first car.
``docs/foxglove/chronos-layout.json`` is ``live_layout(("car1", "car2"), DEMO_TRACK)``;
``crs viz --layout FILE --cars ...`` writes one for other cars or another track.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import foxglove.layouts as fl
import numpy as np

from crs_core.track import Track
from ros4crs.viz_scene import SCENE_CHANNEL, status_channel

__all__ = ["layout_json", "live_layout"]

#: Space around the track in the 3D panel's view, as a fraction of its larger extent.
VIEW_MARGIN = 0.15


def live_layout(cars: Sequence[str], track: Track) -> fl.Layout:
    """The live view's layout for ``cars`` (namespaces without the slash) racing ``track``.

    ``ValueError`` when ``cars`` is empty.
    """
    if not cars:
        raise ValueError("cars: at least one car is needed")
    width = float(np.ptp(track.x))
    height = float(np.ptp(track.y))
    centre = (float(track.x.min()) + width / 2, float(track.y.min()) + height / 2, 0.0)
    scene = fl.ThreeDeePanel(
        title="Track (world)",
        config=fl.ThreeDeeConfig(
            follow_tf="world",
            follow_mode="follow-none",
            topics={SCENE_CHANNEL: fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
            camera_state=fl.ThreeDeeCameraState(
                perspective=False,  # a map, x to the right and y up
                phi=0.0,
                theta_offset=0.0,
                target=centre,
                distance=round((1 + 2 * VIEW_MARGIN) * max(width, height), 2),
            ),
        ),
    )
    statuses = fl.StateTransitionsPanel(
        title="Estimate status",
        config=fl.StateTransitionsConfig(
            paths=[
                fl.StateTransitionsSeries(value=f"{status_channel(car)}.status", label=car)
                for car in cars
            ]
        ),
    )
    plot = fl.PlotPanel(
        title="Solve time (ms) and laps",
        config=fl.PlotConfig(
            show_legend=True,
            paths=[
                fl.PlotSeries(
                    enabled=True, label=f"{car} {label}", value=f"{status_channel(car)}.{field}"
                )
                for field, label in (("solve_ms", "solve ms"), ("laps", "laps"))
                for car in cars
            ],
        ),
    )
    raw = fl.RawMessagesPanel(
        title=f"{cars[0]} status", config=fl.RawMessagesConfig(topic_path=status_channel(cars[0]))
    )
    side = fl.SplitContainer(
        direction="column",
        items=[fl.SplitItem(proportion=1, content=panel) for panel in (statuses, plot, raw)],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=2, content=scene),
                fl.SplitItem(proportion=1, content=side),
            ],
        )
    )


def layout_json(layout: fl.Layout) -> str:
    """The layout as the file the Foxglove app imports (indented, one trailing newline)."""
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"
