"""``ringtrack bench``: speed measurements reported as a rich table and JSON (never timed tests)."""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from importlib import metadata
from pathlib import Path

from rich.table import Table

from tools.console import UsageError, err, out, write_json
from tools.experiment import robot_list, stationary_experiment
from world import engine
from world.scenario import load_scenario


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("bench", help="measure speed (engine, emulator)")
    kinds = parser.add_subparsers(dest="bench", required=True, metavar="BENCHMARK")
    engine_parser = kinds.add_parser(
        "engine",
        help="in-process engine: one run, the 30-trial N = 6 experiment, the N = 3..30 sweep",
    )
    engine_parser.add_argument("--trials", type=int, default=30)
    engine_parser.add_argument("--sweep", type=str, default="3-30", help="team sizes of the sweep, e.g. 3-30")
    engine_parser.add_argument("--json", type=Path, metavar="PATH")
    engine_parser.set_defaults(handler=run_engine_bench)

    emulator_parser = kinds.add_parser(
        "emulator",
        help="lockstep steps per second of a multi-process team over Zenoh, bytes per message, memory",
    )
    emulator_parser.add_argument("--robots", type=robot_list, default=[6], help="team size or list, e.g. 6,12,24")
    emulator_parser.add_argument("--steps", type=int, default=1000)
    emulator_parser.add_argument("--strategy", choices=["self", "constant"], default="self")
    emulator_parser.add_argument("--repeat", type=int, default=1, help="runs per configuration; medians reported")
    emulator_parser.add_argument("--dashboard", choices=["off", "on", "compare"], default="off",
                                 help="draw the dashboard (to RUN_FOLDER/monitor.stdout), or alternate runs "
                                 "without and with it to measure what it costs")
    emulator_parser.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR")
    emulator_parser.add_argument("--json", type=Path, metavar="PATH")
    emulator_parser.set_defaults(handler=run_emulator_bench)


def machine() -> dict[str, object]:
    """Core count, Python and library versions that a benchmark result depends on."""
    versions = {name: metadata.version(name) for name in ("numpy", "eclipse-zenoh", "msgspec", "filterpy")}
    return {
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "versions": versions,
    }


def parse_range(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def run_engine_bench(args: argparse.Namespace) -> int:
    results: dict[str, object] = {"benchmark": "engine", "machine": machine()}
    scenario = load_scenario("paper-stationary")
    started = time.perf_counter()
    history = engine.run(scenario, steps=scenario.max_steps, record_positions=False)
    elapsed = time.perf_counter() - started
    results["single_run"] = {"robots": scenario.robots, "steps": history.steps, "steps_per_s": history.steps / elapsed}

    err.print(f"running the {args.trials}-trial two-strategy experiment for N = 6 ...")
    experiment = stationary_experiment("paper-stationary", [6], args.trials, 0)
    results["experiment_n6"] = {"trials": args.trials, "wall_s": experiment["wall_s"]}

    sizes = parse_range(args.sweep)
    err.print(f"running the sweep N = {sizes[0]}..{sizes[-1]} x {args.trials} trials ...")
    sweep = stationary_experiment("paper-stationary", sizes, args.trials, 0)
    results["sweep"] = {"robots": f"{sizes[0]}..{sizes[-1]}", "trials": args.trials, "wall_s": sweep["wall_s"]}

    table = Table(title=f"engine benchmark ({results['machine']['cores']} cores)")
    table.add_column("measurement")
    table.add_column("result", justify="right")
    table.add_row(f"one run, N = {scenario.robots}", f"{results['single_run']['steps_per_s']:.0f} steps/s")
    table.add_row(f"experiment N = 6, {args.trials} trials x 2 strategies", f"{experiment['wall_s']:.2f} s")
    table.add_row(f"sweep N = {sizes[0]}..{sizes[-1]}, {args.trials} trials x 2", f"{sweep['wall_s']:.2f} s")
    out.print(table)
    if args.json:
        write_json(args.json, results)
    return 0


def run_emulator_bench(args: argparse.Namespace) -> int:
    from tools.spawn import spawn_team

    if args.repeat < 1:
        raise UsageError(f"--repeat {args.repeat}: give at least 1")
    modes = [False, True] if args.dashboard == "compare" else [args.dashboard == "on"]
    rows = []
    for robots in args.robots:
        scenario = load_scenario("paper-stationary", robots=robots, strategy=args.strategy, max_steps=args.steps)
        speeds: dict[bool, list[float]] = {mode: [] for mode in modes}
        for attempt in range(args.repeat):
            for dashboard in modes:
                err.print(f"{robots} robots, {args.steps} lockstep steps, dashboard {'on' if dashboard else 'off'} "
                          f"(run {attempt + 1}/{args.repeat}) ...")
                result = spawn_team(scenario, clock="lockstep", runs=args.runs, dashboard=dashboard, quiet=True)
                if result["exit_code"] != 0:
                    err.print(f"the {robots}-robot run failed: {result.get('failures')}; see {result['folder']}")
                    return 1
                speeds[dashboard].append(result["steps_per_s"])
        by_kind = result["by_kind"]
        robot_rss = [kib for name, kib in result["rss_kib"].items() if name.startswith("r")]
        row = {
            "robots": robots,
            "steps": result["steps"],
            "steps_per_s": statistics.median(speeds[modes[0]]),
            "runs_steps_per_s": speeds[modes[0]],
            "bytes_per_message": {
                kind: entry["bytes"] / entry["messages"] for kind, entry in sorted(by_kind.items()) if entry["messages"]
            },
            "robot_rss_mib": max(robot_rss) / 1024 if robot_rss else None,
            "world_rss_mib": result["rss_kib"].get("world", 0) / 1024,
            "run_folder": result["folder"],
        }
        if args.dashboard == "compare":
            row["runs_steps_per_s_with_dashboard"] = speeds[True]
            row["steps_per_s_with_dashboard"] = statistics.median(speeds[True])
            row["dashboard_cost"] = 1.0 - row["steps_per_s_with_dashboard"] / row["steps_per_s"]
        rows.append(row)
    results = {"benchmark": "emulator", "machine": machine(), "strategy": args.strategy, "rows": rows}
    if len(rows) == 1:
        results["steps_per_s"] = rows[0]["steps_per_s"]
    table = Table(title=f"lockstep emulator ({results['machine']['cores']} cores, {args.strategy} strategy)")
    for column in ("robots", "steps/s", "request B", "reply B", "measurement B", "command B", "robot RSS MiB"):
        table.add_column(column, justify="right")
    if args.dashboard == "compare":
        table.add_column("with dashboard", justify="right")
        table.add_column("cost", justify="right")
    for row in rows:
        size = row["bytes_per_message"]
        table.add_row(
            str(row["robots"]),
            f"{row['steps_per_s']:.0f}",
            *(f"{size.get(kind, 0):.1f}" for kind in ("request", "reply", "measurement", "command")),
            f"{row['robot_rss_mib']:.1f}" if row["robot_rss_mib"] else "-",
            *([f"{row['steps_per_s_with_dashboard']:.0f}", f"{row['dashboard_cost']:+.1%}"]
              if args.dashboard == "compare" else []),
        )
    out.print(table)
    if args.json:
        write_json(args.json, results)
    return 0
