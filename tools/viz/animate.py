"""``ringtrack plot LOG --animate FILE.gif|FILE.mp4``: the team over time, one frame every K steps.

Each frame shows the region, every robot (grey once it left), the true target, each robot's estimate
with its 2-sigma covariance ellipse (the fusion centre's alone under centralized estimation) and the
ring links its messages crossed in that step, coloured by kind (red where a message was dropped), as
the Foxglove scene draws them (:mod:`tools.viz.scene`). Positions in metres; the title gives the step
and the simulated time in seconds. GIFs are written with pillow, MP4 with ffmpeg (when on PATH).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
from matplotlib.figure import Figure

from ringtrack.tools.output.console import UsageError
from ringtrack.tools.runlog.derived import covariance_ellipse, fired_links
from ringtrack.tools.runlog.log import RunLog
from ringtrack.tools.viz.scene import DROPPED, GONE, LINK_COLOURS, ROBOT_COLOURS

ANIMATION_SUFFIXES = (".gif", ".mp4")


def frame_steps(steps: int, every: int) -> list[int]:
    """Indices of the step records drawn: the first and then every ``every``-th (ceil(steps / every))."""
    return list(range(0, steps, every))


def animate_run(log: RunLog, path: Path, fps: int = 10, every: int = 1, dpi: int = 80) -> int:
    """Write the animation of ``log`` to ``path`` (.gif or .mp4); returns the number of frames."""
    if path.suffix.lower() == ".mp4" and not FFMpegWriter.isAvailable():
        raise UsageError(f"--animate {path}: writing MP4 needs ffmpeg on PATH; install it or give a .gif")
    scenario = log.scenario
    events: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for event in log.events:
        events[event.get("step") or 0].append(event)
    rows = frame_steps(len(log.steps), every)
    centralized, known = scenario.estimation.mode == "centralized", scenario.estimation.mode == "known"

    figure = Figure(figsize=(6, 6), layout="constrained")
    axes = figure.subplots()
    vertices = scenario.region.vertices
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    margin = 0.08 * float((high - low).max())

    def draw(index: int) -> None:
        record = log.steps[rows[index]]
        axes.clear()
        outline = np.vstack([vertices, vertices[:1]])
        axes.plot(outline[:, 0], outline[:, 1], color="black", linewidth=1)
        positions = np.asarray(record["positions"], dtype=float)
        for link in fired_links(record, events.get(record["step"], ())):
            (x0, y0), (x1, y1) = positions[link.sender], positions[link.receiver]
            colour = DROPPED if link.dropped else LINK_COLOURS[link.kind]
            axes.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": colour[:3], "lw": 1.2,
                                                              "connectionstyle": "arc3,rad=0.15"})
            if link.dropped:
                axes.plot((x0 + x1) / 2, (y0 + y1) / 2, "x", color=colour[:3], markersize=8)
        live = set(record["live"])
        covariances = record.get("covariance") or [None] * len(positions)
        drawn_fusion = False
        for robot, (x, y) in enumerate(positions):
            colour = ROBOT_COLOURS[robot % len(ROBOT_COLOURS)] if robot in live else GONE
            axes.plot(x, y, "o", color=colour[:3], markersize=7)
            axes.annotate(f"r{robot}", (x, y), textcoords="offset points", xytext=(5, 5), fontsize=7)
            centre, covariance = record["centre"][robot], covariances[robot]
            if known or centre is None or (centralized and drawn_fusion):
                continue
            drawn_fusion = centralized
            shade = (0.85, 0.65, 0.13) if centralized else colour[:3]
            axes.plot(*centre, "+", color=shade, markersize=8)
            if covariance is not None:
                ring = covariance_ellipse(centre, covariance)
                ring = np.vstack([ring, ring[:1]])
                axes.plot(ring[:, 0], ring[:, 1], color=shade, linewidth=0.9)
        axes.plot(*record["target"], "X", color="black", markersize=10, markeredgecolor="white")
        axes.set_xlim(low[0] - margin, high[0] + margin)
        axes.set_ylim(low[1] - margin, high[1] + margin)
        axes.set_aspect("equal")
        axes.set_xlabel("x (m)")
        axes.set_ylabel("y (m)")
        axes.set_title(f"{scenario.name}: step {record['step']}, t = {record['time']:.1f} s", fontsize=10)

    animation = FuncAnimation(figure, draw, frames=len(rows), repeat=False)
    writer = PillowWriter(fps=fps) if path.suffix.lower() == ".gif" else FFMpegWriter(fps=fps)
    logging.getLogger("matplotlib.animation").setLevel(logging.WARNING)  # its INFO line says nothing to a user
    animation.save(str(path), writer=writer, dpi=dpi)
    return len(rows)
