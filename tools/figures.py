"""Figures drawn with matplotlib's headless Agg backend."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STRATEGY_COLOURS = {"constant": "tab:blue", "self": "tab:orange"}
STRATEGY_LABELS = {"constant": "constant", "self": "self-triggered"}


def stationary_comparison(result: dict, path: Path) -> None:
    """The paper's comparison figure: Ctime and Com-bar (mean +- std) per strategy; a sweep over team
    sizes draws them against N."""
    sizes = result["robots"]
    figure, (left, right) = plt.subplots(1, 2, figsize=(9, 3.6), constrained_layout=True)
    for strategy in ("constant", "self"):
        entries = [entry for entry in result["summary"] if entry["strategy"] == strategy and entry["ctime_mean"]]
        style = {"color": STRATEGY_COLOURS[strategy], "label": STRATEGY_LABELS[strategy], "capsize": 4}
        if len(sizes) == 1:
            position = [0 if strategy == "constant" else 1]
            for axis, key in ((left, "ctime"), (right, "com_bar")):
                axis.bar(position, [e[f"{key}_mean"] for e in entries], yerr=[e[f"{key}_std"] for e in entries], **style)
        else:
            dodge = 0.012 * (max(sizes) - min(sizes)) * (-1 if strategy == "constant" else 1)
            robots = [entry["robots"] + dodge for entry in entries]
            for axis, key in ((left, "ctime"), (right, "com_bar")):
                axis.errorbar(robots, [e[f"{key}_mean"] for e in entries], yerr=[e[f"{key}_std"] for e in entries],
                              marker="o", **style)
    if len(sizes) == 1:
        for axis in (left, right):
            axis.set_xticks([0, 1], [STRATEGY_LABELS["constant"], STRATEGY_LABELS["self"]])
        title = f"N = {sizes[0]}, {result['trials']} random starts"
    else:
        for axis in (left, right):
            axis.set_xlabel("robots N")
            axis.set_xticks(sizes)
            axis.legend()
        title = f"{result['trials']} random starts per team size"
    left.set_ylabel("Ctime (steps)")
    left.set_title("(a) convergence time")
    right.set_ylabel("Com-bar (polls per robot per step)")
    right.set_title("(b) communication")
    right.set_ylim(0, 1.1)
    figure.suptitle(f"Stationary target: constant vs self-triggered ({title})")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
