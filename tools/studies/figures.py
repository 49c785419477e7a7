"""Figures drawn with matplotlib's headless Agg backend."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ringtrack.tools.studies.experiment import MovingRun, MovingStudy, StationaryCell, StationaryStudy
from ringtrack.tools.studies.nemesis import NemesisStudy
from ringtrack.tools.studies.robustness import METRICS, MOVING_METRICS, FaultStudy, FaultSummary

# A study's strategies (or runs) take these colours in the order the study compares them.
PALETTE = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive",
           "tab:cyan")


def drawn(value: float | None) -> float:
    """A figure as drawn: NaN (no point) where it is unknown."""
    return math.nan if value is None else value


def colour(position: int) -> str:
    """The colour of a study's strategy (or run) at ``position`` in the order it compares them."""
    return PALETTE[position % len(PALETTE)]


def stationary_comparison(result: StationaryStudy, path: Path) -> None:
    """The paper's comparison figure: Ctime and Com-bar (mean +- std) per strategy; a sweep over team
    sizes draws them against N."""
    sizes = result.robots
    strategies = list(result.labels)
    figure, (left, right) = plt.subplots(1, 2, figsize=(9, 4.0), layout="constrained")
    measures: tuple[tuple[Any, Callable[[StationaryCell], tuple[float | None, float | None]]], ...] = (
        (left, lambda entry: (entry.ctime_mean, entry.ctime_std)),
        (right, lambda entry: (entry.com_bar_mean, entry.com_bar_std)))
    for index, strategy in enumerate(strategies):
        entries = [entry for entry in result.summary if entry.strategy == strategy and entry.ctime_mean]
        style = {"color": colour(index), "label": result.labels[strategy], "capsize": 4}
        for axis, measure in measures:
            means, sds = zip(*map(measure, entries), strict=True) if entries else ((), ())
            if len(sizes) == 1:
                axis.bar([index], means, yerr=sds, **style)
            else:
                spread = (2 * index - (len(strategies) - 1)) / max(1, len(strategies) - 1)  # -1 .. 1
                dodge = 0.012 * (max(sizes) - min(sizes)) * spread
                axis.errorbar([entry.robots + dodge for entry in entries], means, yerr=sds, marker="o", **style)
    if len(sizes) == 1:
        for axis in (left, right):
            axis.set_xticks(range(len(strategies)), [result.labels[strategy] for strategy in strategies])
            axis.set_xlabel("strategy")
        title = f"N = {sizes[0]}, {result.trials} random starts"
    else:
        for axis in (left, right):
            axis.set_xlabel("robots N")
            axis.set_xticks(sizes)
        handles, labels = left.get_legend_handles_labels()
        figure.legend(handles, labels, loc="outside lower center", ncols=2)
        title = f"{result.trials} random starts per team size"
    left.set_ylabel("Ctime (steps)")
    left.set_title("(a) convergence time, mean ± 1 sd")
    right.set_ylabel("Com-bar (polls per robot per step)")
    right.set_title("(b) communication, mean ± 1 sd")
    right.set_ylim(0, 1.1)
    heading = f"Stationary target: {' vs '.join(result.labels[strategy] for strategy in strategies)} ({title})"
    separator = "; " if len(heading) < 80 else "\n"  # the constant vs self-triggered heading fits one line
    figure.suptitle(f"{heading}{separator}error bars: ±1 standard deviation over the trials", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def run_styles(result: MovingStudy) -> dict[tuple[str, str], dict[str, Any]]:
    """The line style of each (strategy, estimation mode) of a moving-target study: a colour by its
    position in the comparison, the first dashed and on top (the others often equal it), a label
    from the strategy's own."""
    order = list(dict.fromkeys((run.strategy, run.estimation) for run in result.runs))
    styles: dict[tuple[str, str], dict[str, Any]] = {}
    for position, (strategy, mode) in enumerate(order):
        label = f"{result.labels[strategy]}, {mode} EKF" + (" + CI" if mode == "decentralized" else "")
        styles[strategy, mode] = {"color": colour(position), "label": label,
                                  **({"linestyle": "--", "zorder": 3} if position == 0 else {})}
    return styles


def _time_axis(result: MovingStudy, run: MovingRun) -> list[float]:
    stride = result.series_stride * result.dt
    return [index * stride for index in range(len(run.cerr_series_deg))]


def moving_comparison(result: MovingStudy, path: Path) -> None:
    """Cerr and Terr over time (trial means) of the compared runs at the main setting."""
    runs = [run for run in result.runs if run.group == "comparison"]
    styles = run_styles(result)
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    for run in runs:
        style = styles[run.strategy, run.estimation]
        times = _time_axis(result, run)
        left.plot(times, run.cerr_series_deg, linewidth=1.2, **style)
        right.plot(times, run.terr_series, linewidth=1.2, **style)
    left.set_xlabel("time (s)")
    left.set_ylabel("Cerr (deg, true)")
    left.set_title("(a) convergence error")
    right.set_xlabel("time (s)")
    right.set_ylabel("Terr (m)")
    right.set_yscale("log")
    right.set_title("(b) target estimate error")
    handles, labels = left.get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=8)
    speed, angular = runs[0].speed, runs[0].angular_speed
    figure.suptitle(f"Moving target (v = {speed} m/s, w = {angular} rad/s), mean of {result.trials} trials; "
                    "no convergence threshold: the target never stops")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def moving_velocities(result: MovingStudy, path: Path) -> None:
    """Cerr over time for each target velocity, per run of the velocity settings (by default
    constant + centralized vs self-triggered + decentralized)."""
    runs = [run for run in result.runs if run.group == "velocities"]
    styles = run_styles(result)
    settings = sorted({(run.speed, run.angular_speed) for run in runs}, key=lambda pair: (pair[0], -pair[1]))
    figure, axes = plt.subplots(1, len(settings), figsize=(3.4 * len(settings), 3.8), sharey=True,
                                layout="constrained")
    for axis, (speed, angular) in zip(axes, settings, strict=True):
        for run in (run for run in runs if (run.speed, run.angular_speed) == (speed, angular)):
            axis.plot(_time_axis(result, run), run.cerr_series_deg, linewidth=1.0,
                      **styles[run.strategy, run.estimation])
        axis.set_title(f"v = {speed} m/s, w = {angular} rad/s (r = {speed / angular:.2f} m)", fontsize=9)
        axis.set_xlabel("time (s)")
    axes[0].set_ylabel("Cerr (deg, true)")
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
    figure.suptitle(f"Cerr against target velocity and radius, mean of {result.trials} trials")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


SWEPT_LABELS = {"drop": "drop probability", "outage_steps": "partition outage (steps)",
                "communication_range": "communication range r_c (m)"}
SWEPT_SHORT = {"drop": "drop", "outage_steps": "outage (steps)", "communication_range": "r_c (m)"}
VARIANT_STYLES = {"centralized": "-", "decentralized": "--"}
MARKERS = "os^Dv"  # one per value of a second swept quantity


def robustness_curves(result: FaultStudy, path: Path) -> None:
    """Every quantity of ``experiment faults`` against the swept one: mean with +-1 sd error bars
    over the trials, one line per strategy (and estimation mode, and value of any other swept
    quantity). An unlimited communication range is drawn past the largest finite one."""
    metrics = METRICS + (MOVING_METRICS if result.moving else ())
    swept = result.swept or ["drop"]
    axis_key, others = swept[0], swept[1:]
    values = [getattr(cell, axis_key) for cell in result.cells]
    finite = [value for value in values if value is not None]
    unlimited = max(finite) * 1.25 if finite else 1.0
    strategies = list(result.labels)

    def position(value: float | None) -> float:
        return unlimited if value is None else value

    columns = 4 if len(metrics) > 6 else 3
    figure, axes = plt.subplots(2, columns, figsize=(4.0 * columns, 6.6), constrained_layout=True)
    lines: dict[tuple, list[FaultSummary]] = {}
    for entry in result.summary:
        key = (entry.strategy, entry.estimation, *(getattr(entry, name) for name in others))
        lines.setdefault(key, []).append(entry)
    secondary = sorted({tuple(key[2:]) for key in lines}, key=str)
    spread = 0.012 * (max(map(position, values)) or 1.0)
    for number, (key, entries) in enumerate(sorted(lines.items(), key=lambda item: str(item[0]))):
        strategy, mode, *rest = key
        entries.sort(key=lambda entry: position(getattr(entry, axis_key)))
        label = result.labels[strategy] + (f", {mode}" if result.moving else "")
        label += "".join(f", {SWEPT_SHORT[name]} {'unlimited' if value is None else f'{value:g}'}"
                         for name, value in zip(others, rest, strict=True))
        marker = MARKERS[secondary.index(tuple(rest)) % len(MARKERS)]
        style = {"color": colour(strategies.index(strategy)), "linestyle": VARIANT_STYLES.get(mode, "-"),
                 "marker": marker, "markersize": 4, "capsize": 3, "label": label}
        dodge = spread * (number - (len(lines) - 1) / 2)
        xs = [position(getattr(entry, axis_key)) + dodge for entry in entries]
        for axis, (metric, name, unit) in zip(axes.flat, metrics, strict=False):
            means = [np.nan if (mean := entry.mean(metric)) is None else mean for entry in entries]
            sds = [0.0 if (sd := entry.sd(metric)) is None else sd for entry in entries]
            axis.errorbar(xs, means, yerr=sds, **style)
            axis.set_title(name, fontsize=10)
            axis.set_ylabel(unit, fontsize=8)
            if metric == "converged":
                axis.set_ylim(-0.05, 1.05)
    for axis in axes.flat[len(metrics):]:
        axis.set_visible(False)
    for axis in axes.flat[:len(metrics)]:
        axis.set_xlabel(SWEPT_LABELS[axis_key], fontsize=8)
        axis.grid(alpha=0.3)
        if None in values:
            ticks = sorted(set(finite)) + [unlimited]
            axis.set_xticks(ticks, [f"{tick:g}" for tick in ticks[:-1]] + ["none"])
    axes.flat[0].legend(fontsize=7)
    figure.suptitle(f"{result.scenario}, N = {result.robots}: mean ± 1 sd (error bars) over "
                    f"{result.trials} trials per point; {result.costs_span}", fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_schedules(study: NemesisStudy, path: Path) -> None:
    """Where each schedule's ring re-formed and how well it tracked after, by clock; a red cross marks
    a schedule whose books did not balance or whose lives overlapped."""
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    for clock, marker in (("lockstep", "o"), ("realtime", "s")):
        rows = [row for row in study.rows if row.clock == clock]
        top.plot([row.schedule for row in rows], [row.reformed_at_step or float("nan") for row in rows], marker,
                 label=clock, linestyle="none")
        bottom.plot([row.schedule for row in rows], [row.cerr_after_deg or float("nan") for row in rows], marker,
                    label=clock, linestyle="none")
    broken = [row.schedule for row in study.rows if not row.books_balanced or row.overlapping_lives]
    for axis in (top, bottom):
        for schedule in broken:
            axis.axvline(schedule, color="red", linestyle=":")
    top.set_ylabel("ring re-formed at step")
    bottom.set_ylabel("Cerr after (deg)")
    bottom.set_xlabel("schedule")
    top.legend()
    top.set_title(f"{study.schedules} nemesis schedules on {study.scenario}: overlapping lives "
                  f"{study.overlapping_lives}, unbalanced books {study.unbalanced_books}")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
