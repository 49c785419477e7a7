"""``ringtrack plot LOG -o PNG``: a run's trajectories, errors, polls and traffic in one figure."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib import colormaps  # imported here: every ringtrack command builds this parser
from matplotlib.figure import Figure

from ringtrack.bus.counting import robot_link_totals
from ringtrack.tools.runlog.derived import ELLIPSE_SIGMAS, covariance_ellipse
from ringtrack.tools.runlog.log import RunLog, history_from_log

if TYPE_CHECKING:
    from matplotlib.figure import Figure


PANELS = ("(a) trajectories (open: start, filled: end)", "(b) convergence and target errors",
          "(c) polls per robot over time", "(d) robot-to-robot traffic per link (sender>receiver)")


def plot_run(log: RunLog) -> Figure:
    """Four panels titled ``PANELS``: (a) trajectories on the region (a line labelled ``r<i>`` per
    robot; for a moving target also each robot's last estimate with its 2-sigma ellipse), (b) Cerr
    and Terr over time (one point per step), (c) polls per robot over time, (d)
    robot-to-robot messages (and bytes, when counted) per link, as the end record counts them."""
    history = history_from_log(log)
    scenario = history.scenario
    assert history.positions is not None
    positions = history.positions[:, 0]
    seconds = np.arange(history.steps) * scenario.control.dt
    figure = Figure(figsize=(13, 10), layout="constrained")
    trajectories, errors, polls, links = figure.subplots(2, 2).flat

    outline = np.vstack([scenario.region.vertices, scenario.region.vertices[:1]])
    trajectories.plot(outline[:, 0], outline[:, 1], color="black", linewidth=1, label="region boundary")
    colours = colormaps["tab10"](np.arange(scenario.robots) % 10)
    for robot in range(scenario.robots):
        path_xy = positions[:, robot]
        trajectories.plot(path_xy[:, 0], path_xy[:, 1], color=colours[robot], linewidth=1.5, label=f"r{robot}")
        trajectories.plot(*path_xy[0], "o", color=colours[robot], markerfacecolor="white")
        trajectories.plot(*path_xy[-1], "o", color=colours[robot])
    if scenario.estimation.mode != "known" and history.estimates is not None:
        mean_estimate = np.nanmean(history.estimates[:, 0], axis=1)
        trajectories.plot(mean_estimate[:, 0], mean_estimate[:, 1], color="goldenrod", linewidth=0.8, alpha=0.8,
                          label="estimate (mean of robots)", zorder=3)
    if scenario.moving and scenario.estimation.mode != "known":
        _final_beliefs(trajectories, log, colours)
    targets = history.targets[:, 0]  # drawn last and on top: the truth the estimates are judged by
    trajectories.plot(targets[:, 0], targets[:, 1], color="black", linestyle="--", linewidth=1.6,
                      label="true target", zorder=5)
    trajectories.plot(*targets[-1], "X", color="black", markersize=9, markeredgecolor="white", zorder=6,
                      label="true target, end")
    trajectories.set_aspect("equal")
    trajectories.set_xlabel("x (m)")
    trajectories.set_ylabel("y (m)")
    trajectories.set_title(PANELS[0])
    trajectories.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)

    errors.plot(seconds, history.cerr_true[:, 0], label="Cerr, true positions")
    errors.plot(seconds, history.cerr_memory[:, 0], label="Cerr, robots' memory", linewidth=0.8)
    if not scenario.moving:  # convergence means nothing while the target moves
        errors.axhline(np.rad2deg(scenario.threshold), color="grey", linestyle=":",
                       label=f"Ctime threshold ({np.rad2deg(scenario.threshold):.2g} deg)")
    errors.set_yscale("log")
    errors.set_xlabel("time (s)")
    errors.set_ylabel("Cerr (deg)")
    errors.set_title(PANELS[1])
    handles, labels = errors.get_legend_handles_labels()
    if scenario.estimation.mode != "known":
        terr = errors.twinx()
        terr.plot(seconds, history.terr[:, 0], color="tab:green", linewidth=0.8, label="Terr (right axis)")
        terr.set_ylabel("Terr (m)", color="tab:green")
        more_handles, more_labels = terr.get_legend_handles_labels()
        handles, labels = handles + more_handles, labels + more_labels
    errors.legend(handles, labels, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncols=3)

    steps, robots = np.nonzero(history.triggers[:, 0])
    polls.scatter(steps * scenario.control.dt, robots, marker="|", s=40, color=colours[robots])
    polls.set_yticks(range(scenario.robots), [f"r{robot}" for robot in range(scenario.robots)])
    polls.set_xlabel("time (s)")
    polls.set_ylabel("robot")
    polls.set_title(f"{PANELS[2]} ({len(steps)} in all)")

    per_link = robot_link_totals((log.end or {}).get("traffic", []))
    if per_link:
        spots = np.arange(len(per_link))
        counts = np.array([[entry["messages"], entry["bytes"]] for entry in per_link.values()])
        links.bar(spots - 0.2, counts[:, 0], width=0.4, label="messages")
        links.set_xticks(spots, [f"{source}>{destination}" for source, destination in per_link], rotation=60,
                         fontsize=7)
        links.set_ylabel("messages")
        links.set_xlabel("link (sender>receiver)")
        handles, labels = links.get_legend_handles_labels()
        if counts[:, 1].any():
            sizes = links.twinx()
            sizes.bar(spots + 0.2, counts[:, 1], width=0.4, color="tab:orange", label="bytes")
            sizes.set_ylabel("payload bytes", color="tab:orange")
            more_handles, more_labels = sizes.get_legend_handles_labels()
            handles, labels = handles + more_handles, [*labels, "payload bytes (right axis)"]
        links.legend(handles, labels, fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.08), ncols=2,
                     borderaxespad=0.0)
    energy = (log.end or {}).get("energy_j") or {}
    links.set_title(PANELS[3])
    figure.suptitle(f"{scenario.name}: {scenario.robots} robots, {scenario.strategy.name} strategy, "
                    f"{scenario.estimation.mode} target, {history.steps} steps ({log.header['source']})"
                    + (f"; team radio energy {1e3 * sum(map(sum, energy.values())):.2f} mJ" if energy else ""))
    return figure


def _final_beliefs(axes: Any, log: RunLog, colours: Any) -> None:
    """Each robot's estimate at the last step (a cross in its colour) and its 2-sigma ellipse."""
    last = log.steps[-1]
    covariances = last.get("covariance") or [None] * len(last["centre"])
    for robot, (centre, covariance) in enumerate(zip(last["centre"], covariances, strict=True)):
        if centre is None:
            continue
        axes.plot(*centre, "+", color=colours[robot], markersize=9, zorder=4)
        if covariance is not None:
            ring = covariance_ellipse(centre, covariance)
            ring = np.vstack([ring, ring[:1]])
            axes.plot(ring[:, 0], ring[:, 1], color=colours[robot], linewidth=0.8, zorder=4,
                      label=f"{ELLIPSE_SIGMAS:g}-sigma ellipses, last step" if robot == 0 else None)
