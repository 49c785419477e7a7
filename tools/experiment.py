"""``ringtrack experiment stationary``: the paper's comparison of the constant and self-triggered
strategies on the same seeded random starts, over one or several team sizes."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import msgspec
import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich import box
from rich.table import Table

from tools.console import UsageError, err, out, write_json
from world import engine
from world.scenario import Scenario, apply_overrides, parse_scenario, read_scenario_text, resolve

STRATEGIES = ("constant", "self")


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("experiment", help="run the paper's experiments")
    kinds = parser.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    stationary = kinds.add_parser(
        "stationary",
        help="constant vs self-triggered on the same random starts (Ctime, Com-bar)",
        description="Run both strategies on the same seeded random starts (trial t uses seed S + t) "
        "and compare Ctime and Com-bar; --robots 3,6,10,20 sweeps team sizes.",
    )
    stationary.add_argument("scenario", nargs="?", default="paper-stationary", help="base scenario")
    stationary.add_argument("--robots", type=robot_list, default=[6], help="team size or list, e.g. 3,6,10,20")
    stationary.add_argument("--trials", type=int, default=30, help="random starts per team size (default 30)")
    stationary.add_argument("--seed", type=int, default=0, help="seed of trial 0 (default 0)")
    stationary.add_argument("--sigma-deg", type=float, help="trigger tolerance sigma in degrees")
    stationary.add_argument("--law", choices=["prop", "deadbeat"], help="fresh-information law")
    stationary.add_argument("--steps", type=int, help="step limit per trial (default: control.max_steps)")
    stationary.add_argument("--json", type=Path, metavar="PATH", help="write per-trial rows and means")
    stationary.add_argument("--plot", type=Path, metavar="PNG", help="draw the comparison figure")
    stationary.set_defaults(handler=run_stationary)


def robot_list(text: str) -> list[int]:
    """Parse ``6`` or ``3,6,10,20`` into team sizes of at least 3."""
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--robots {text!r}: give integers like 6 or 3,6,10,20") from None
    if not sizes or min(sizes) < 3:
        raise argparse.ArgumentTypeError(f"--robots {text!r}: every team needs at least 3 robots")
    return sizes


def random_start_scenarios(base: str, robots: int, **overrides: object) -> dict[str, Scenario]:
    """The base scenario with ``robots`` robots, random starts and default threshold, per strategy."""
    text, label = read_scenario_text(base)
    spec = parse_scenario(text, label)
    spec = msgspec.structs.replace(spec, team=msgspec.structs.replace(spec.team, angles_deg=None))
    return {
        strategy: resolve(apply_overrides(spec, robots=robots, strategy=strategy, **overrides), label)
        for strategy in STRATEGIES
    }


def stationary_experiment(
    base: str,
    robots: Sequence[int],
    trials: int,
    seed: int,
    on_step: Callable[[int, str, int], None] | None = None,
    **overrides: object,
) -> dict:
    """Run both strategies for every team size on seeds ``seed .. seed + trials - 1``.

    Returns the JSON-ready result: per-trial ``rows``, per (robots, strategy) ``summary`` with mean
    and standard deviation of Ctime and Com-bar, and per team size ``ratios`` self / constant.
    ``on_step(robots, strategy, step)`` reports progress.
    """
    if trials < 1:
        raise UsageError(f"--trials {trials}: give at least 1 trial")
    seeds = list(range(seed, seed + trials))
    rows: list[dict] = []
    summary: list[dict] = []
    ratios: list[dict] = []
    started = time.perf_counter()
    for size in robots:
        scenarios = random_start_scenarios(base, size, **overrides)
        means: dict[str, dict] = {}
        for strategy, scenario in scenarios.items():
            report = None if on_step is None else (lambda k, s=strategy, n=size: on_step(n, s, k))
            history = engine.run(scenario, seeds, until_converged=True, record_positions=False, on_step=report)
            ctime, com_bar = history.ctime, history.com_bar
            for index, trial_seed in enumerate(seeds):
                rows.append(
                    {
                        "robots": size,
                        "strategy": strategy,
                        "trial": index,
                        "seed": trial_seed,
                        "converged": bool(ctime[index] > 0),
                        "ctime": int(ctime[index]) or None,
                        "ctime_true": int(history.ctime_true[index]) or None,
                        "com_bar": None if ctime[index] == 0 else float(com_bar[index]),
                        "triggers": int((history.triggers[:, index] != 0).sum()),
                    }
                )
            done = ctime > 0
            means[strategy] = {
                "robots": size,
                "strategy": strategy,
                "trials": trials,
                "converged": int(done.sum()),
                "ctime_mean": float(ctime[done].mean()) if done.any() else None,
                "ctime_std": float(ctime[done].std()) if done.any() else None,
                "com_bar_mean": float(com_bar[done].mean()) if done.any() else None,
                "com_bar_std": float(com_bar[done].std()) if done.any() else None,
                "sigma_deg": float(np.rad2deg(scenario.control.sigma)),
                "law": scenario.control.law,
                "threshold_deg": float(np.rad2deg(scenario.threshold)),
            }
            summary.append(means[strategy])
        constant, triggered = means["constant"], means["self"]
        if constant["ctime_mean"] and triggered["ctime_mean"]:
            ratios.append(
                {
                    "robots": size,
                    "ctime_ratio": triggered["ctime_mean"] / constant["ctime_mean"],
                    "com_bar_ratio": triggered["com_bar_mean"] / constant["com_bar_mean"],
                }
            )
    return {
        "experiment": "stationary",
        "scenario": base,
        "seed": seed,
        "trials": trials,
        "robots": list(robots),
        "wall_s": time.perf_counter() - started,
        "summary": summary,
        "ratios": ratios,
        "rows": rows,
    }


def run_stationary(args: argparse.Namespace) -> int:
    overrides = {"sigma_deg": args.sigma_deg, "law": args.law, "max_steps": args.steps}
    # Validate the scenario and flags before showing any progress.
    limit = random_start_scenarios(args.scenario, args.robots[0], **overrides)["self"].max_steps
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=err, transient=False) as progress:
        tasks = {
            (size, strategy): progress.add_task(f"N={size:<3} {strategy:<8}", total=limit)
            for size in args.robots
            for strategy in STRATEGIES
        }

        def on_step(size: int, strategy: str, step: int) -> None:
            if step % 50 == 0:
                progress.update(tasks[size, strategy], completed=step)

        result = stationary_experiment(args.scenario, args.robots, args.trials, args.seed, on_step, **overrides)
        for task in tasks.values():
            progress.update(task, completed=limit)
    out.print(results_table(result))
    if args.json:
        write_json(args.json, result)
    if args.plot:
        from tools.figures import stationary_comparison

        stationary_comparison(result, args.plot)
    failed = [entry for entry in result["summary"] if entry["converged"] < entry["trials"]]
    for entry in failed:
        err.print(
            f"warning: {entry['trials'] - entry['converged']} of {entry['trials']} {entry['strategy']} trials "
            f"with {entry['robots']} robots did not converge within the step limit",
            highlight=False,
        )
    return 1 if failed else 0


def results_table(result: dict) -> Table:
    """Mean +- std of Ctime and Com-bar per team size and strategy, with the self / constant ratios."""
    table = Table(title=f"stationary target, {result['trials']} trials (seeds {result['seed']}..), Ctime in steps, "
                  "s/c = self / constant", title_justify="left", box=box.SIMPLE_HEAD)
    for column in ("N", "strategy", "done", "Ctime", "Com-bar", "Ctime s/c", "Com s/c"):
        table.add_column(column, justify="right", no_wrap=True)
    ratios = {entry["robots"]: entry for entry in result["ratios"]}
    for entry in result["summary"]:
        ratio = ratios.get(entry["robots"]) if entry["strategy"] == "self" else None
        table.add_row(
            str(entry["robots"]),
            entry["strategy"],
            f"{entry['converged']}/{entry['trials']}",
            _mean_std(entry["ctime_mean"], entry["ctime_std"], ".1f"),
            _mean_std(entry["com_bar_mean"], entry["com_bar_std"], ".3f"),
            f"{ratio['ctime_ratio']:.3f}" if ratio else "",
            f"{ratio['com_bar_ratio']:.3f}" if ratio else "",
        )
    return table


def _mean_std(mean: float | None, std: float | None, spec: str) -> str:
    return "-" if mean is None else f"{mean:{spec}} ± {std:{spec}}"
