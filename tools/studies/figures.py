"""Figures drawn with matplotlib's headless Agg backend."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ringtrack.tools.studies.robustness import METRICS, MOVING_METRICS

STRATEGY_COLOURS = {"constant": "tab:blue", "self": "tab:orange", "plan": "tab:green"}
STRATEGY_LABELS = {"constant": "constant", "self": "self-triggered", "plan": "plan replies"}


def stationary_comparison(result: dict, path: Path) -> None:
    """The paper's comparison figure: Ctime and Com-bar (mean +- std) per strategy; a sweep over team
    sizes draws them against N."""
    sizes = result["robots"]
    strategies = result.get("strategies", ["constant", "self"])
    figure, (left, right) = plt.subplots(1, 2, figsize=(9, 4.0), layout="constrained")
    for index, strategy in enumerate(strategies):
        entries = [entry for entry in result["summary"] if entry["strategy"] == strategy and entry["ctime_mean"]]
        style = {"color": STRATEGY_COLOURS[strategy], "label": STRATEGY_LABELS[strategy], "capsize": 4}
        if len(sizes) == 1:
            position = [index]
            for axis, key in ((left, "ctime"), (right, "com_bar")):
                axis.bar(position, [e[f"{key}_mean"] for e in entries], yerr=[e[f"{key}_std"] for e in entries],
                         **style)
        else:
            spread = (2 * index - (len(strategies) - 1)) / max(1, len(strategies) - 1)  # -1 .. 1
            dodge = 0.012 * (max(sizes) - min(sizes)) * spread
            robots = [entry["robots"] + dodge for entry in entries]
            for axis, key in ((left, "ctime"), (right, "com_bar")):
                axis.errorbar(robots, [e[f"{key}_mean"] for e in entries], yerr=[e[f"{key}_std"] for e in entries],
                              marker="o", **style)
    if len(sizes) == 1:
        for axis in (left, right):
            axis.set_xticks(range(len(strategies)), [STRATEGY_LABELS[strategy] for strategy in strategies])
            axis.set_xlabel("strategy")
        title = f"N = {sizes[0]}, {result['trials']} random starts"
    else:
        for axis in (left, right):
            axis.set_xlabel("robots N")
            axis.set_xticks(sizes)
        handles, labels = left.get_legend_handles_labels()
        figure.legend(handles, labels, loc="outside lower center", ncols=2)
        title = f"{result['trials']} random starts per team size"
    left.set_ylabel("Ctime (steps)")
    left.set_title("(a) convergence time, mean ± 1 sd")
    right.set_ylabel("Com-bar (polls per robot per step)")
    right.set_title("(b) communication, mean ± 1 sd")
    right.set_ylim(0, 1.1)
    heading = f"Stationary target: {' vs '.join(STRATEGY_LABELS[strategy] for strategy in strategies)} ({title})"
    separator = "; " if len(heading) < 80 else "\n"  # the constant vs self-triggered heading fits one line
    figure.suptitle(f"{heading}{separator}error bars: ±1 standard deviation over the trials", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


RUN_STYLES: dict[tuple[str, str], dict[str, Any]] = {
    ("constant", "centralized"): {"color": "tab:blue", "linestyle": "--", "zorder": 3,  # on top: often equal
                                  "label": "constant, centralized EKF"},
    ("self", "centralized"): {"color": "tab:orange", "label": "self-triggered, centralized EKF"},
    ("self", "decentralized"): {"color": "tab:green", "label": "self-triggered, decentralized EKF + CI"},
}


def run_style(strategy: str, mode: str) -> dict[str, Any]:
    """The line style of a moving-target run: the paper's three fixed, any other strategy by its name."""
    if (strategy, mode) in RUN_STYLES:
        return RUN_STYLES[strategy, mode]
    others = ["tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan"]
    colour = others[sum(map(ord, strategy + mode)) % len(others)]
    return {"color": colour, "linestyle": ":" if mode == "centralized" else "-",
            "label": f"{strategy}, {mode} EKF" + (" + CI" if mode == "decentralized" else "")}


def _time_axis(result: dict, run: dict) -> list[float]:
    stride = result["series_stride"] * result["dt"]
    return [index * stride for index in range(len(run["cerr_series_deg"]))]


def moving_comparison(result: dict, path: Path) -> None:
    """Cerr and Terr over time (trial means) of the three strategies at the main setting."""
    runs = [run for run in result["runs"] if run["group"] == "comparison"]
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4.2), layout="constrained")
    for run in runs:
        style = run_style(run["strategy"], run["estimation"])
        times = _time_axis(result, run)
        left.plot(times, run["cerr_series_deg"], linewidth=1.2, **style)
        right.plot(times, run["terr_series"], linewidth=1.2, **style)
    left.set_xlabel("time (s)")
    left.set_ylabel("Cerr (deg, true)")
    left.set_title("(a) convergence error")
    right.set_xlabel("time (s)")
    right.set_ylabel("Terr (m)")
    right.set_yscale("log")
    right.set_title("(b) target estimate error")
    handles, labels = left.get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=8)
    speed, angular = runs[0]["speed"], runs[0]["angular_speed"]
    figure.suptitle(f"Moving target (v = {speed} m/s, w = {angular} rad/s), mean of {result['trials']} trials; "
                    "no convergence threshold: the target never stops")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def moving_velocities(result: dict, path: Path) -> None:
    """Cerr over time for each target velocity: constant + centralized vs self-triggered + decentralized."""
    runs = [run for run in result["runs"] if run["group"] == "velocities"]
    settings = sorted({(run["speed"], run["angular_speed"]) for run in runs}, key=lambda pair: (pair[0], -pair[1]))
    figure, axes = plt.subplots(1, len(settings), figsize=(3.4 * len(settings), 3.8), sharey=True,
                                layout="constrained")
    for axis, (speed, angular) in zip(axes, settings, strict=True):
        for run in (run for run in runs if (run["speed"], run["angular_speed"]) == (speed, angular)):
            axis.plot(_time_axis(result, run), run["cerr_series_deg"], linewidth=1.0,
                      **run_style(run["strategy"], run["estimation"]))
        axis.set_title(f"v = {speed} m/s, w = {angular} rad/s (r = {speed / angular:.2f} m)", fontsize=9)
        axis.set_xlabel("time (s)")
    axes[0].set_ylabel("Cerr (deg, true)")
    handles, labels = axes[0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
    figure.suptitle(f"Cerr against target velocity and radius, mean of {result['trials']} trials")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


SWEPT_LABELS = {"drop": "drop probability", "outage_steps": "partition outage (steps)",
                "communication_range": "communication range r_c (m)"}
SWEPT_SHORT = {"drop": "drop", "outage_steps": "outage (steps)", "communication_range": "r_c (m)"}
VARIANT_STYLES = {"centralized": "-", "decentralized": "--"}
MARKERS = "os^Dv"  # one per value of a second swept quantity


def robustness_curves(result: dict, path: Path) -> None:
    """Every quantity of ``experiment faults`` against the swept one: mean with +-1 sd error bars
    over the trials, one line per strategy (and estimation mode, and value of any other swept
    quantity). An unlimited communication range is drawn past the largest finite one."""
    metrics = METRICS + (MOVING_METRICS if result["moving"] else ())
    swept = result["swept"] or ["drop"]
    axis_key, others = swept[0], swept[1:]
    finite = [cell[axis_key] for cell in result["cells"] if cell[axis_key] is not None]
    unlimited = max(finite) * 1.25 if finite else 1.0

    def position(value: float | None) -> float:
        return unlimited if value is None else value

    columns = 4 if len(metrics) > 6 else 3
    figure, axes = plt.subplots(2, columns, figsize=(4.0 * columns, 6.6), constrained_layout=True)
    lines: dict[tuple, list[dict]] = {}
    for entry in result["summary"]:
        key = (entry["strategy"], entry["estimation"], *(entry[name] for name in others))
        lines.setdefault(key, []).append(entry)
    secondary = sorted({tuple(key[2:]) for key in lines}, key=str)
    spread = 0.012 * (max(map(position, [c[axis_key] for c in result["cells"]])) or 1.0)
    for number, (key, entries) in enumerate(sorted(lines.items(), key=lambda item: str(item[0]))):
        strategy, mode, *rest = key
        entries.sort(key=lambda entry: position(entry[axis_key]))
        label = STRATEGY_LABELS[strategy] + (f", {mode}" if result["moving"] else "")
        label += "".join(f", {SWEPT_SHORT[name]} {'unlimited' if value is None else f'{value:g}'}"
                         for name, value in zip(others, rest, strict=True))
        marker = MARKERS[secondary.index(tuple(rest)) % len(MARKERS)]
        style = {"color": STRATEGY_COLOURS[strategy], "linestyle": VARIANT_STYLES.get(mode, "-"), "marker": marker,
                 "markersize": 4, "capsize": 3, "label": label}
        dodge = spread * (number - (len(lines) - 1) / 2)
        xs = [position(entry[axis_key]) + dodge for entry in entries]
        for axis, (metric, name, unit) in zip(axes.flat, metrics, strict=False):
            means = [np.nan if entry[f"{metric}_mean"] is None else entry[f"{metric}_mean"] for entry in entries]
            sds = [0.0 if entry[f"{metric}_sd"] is None else entry[f"{metric}_sd"] for entry in entries]
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
        if None in [cell[axis_key] for cell in result["cells"]]:
            ticks = sorted(set(finite)) + [unlimited]
            axis.set_xticks(ticks, [f"{tick:g}" for tick in ticks[:-1]] + ["none"])
    axes.flat[0].legend(fontsize=7)
    costs = "costs over each whole run" if result["moving"] else "costs to Ctime"
    figure.suptitle(f"{result['scenario']}, N = {result['robots']}: mean ± 1 sd (error bars) over "
                    f"{result['trials']} trials per point; {costs}", fontsize=11)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)
