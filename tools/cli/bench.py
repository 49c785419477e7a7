"""``ringtrack bench engine|emulator|latency|studies|suite``: how fast the engine, a team, a round trip and the
studies run."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rich.table import Table

from ringtrack.agents.strategy import REGISTRY
from ringtrack.tools.bench.bench import (
    MESSAGE_KINDS,
    SUITE_TEAMS,
    BenchFailed,
    emulator_row,
    engine_results,
    machine,
    neighbour_round_trip,
    suite_ratios,
)
from ringtrack.tools.bench.record import record_cost
from ringtrack.tools.bench.studies import FULL, QUICK, TARGETS, THROUGHPUT, studies_results, targets_met
from ringtrack.tools.cli.experiment import robot_list
from ringtrack.tools.cli.options import JSON_FILE, at_least, team_sizes
from ringtrack.tools.output.console import UsageError, err, out, show
from ringtrack.tools.output.files import write_json
from ringtrack.tools.viz.extra import require_sdk


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("bench", help="measure speed (engine, emulator, latency, studies, suite)")
    kinds = parser.add_subparsers(dest="bench", required=True, metavar="BENCHMARK")
    engine_parser = kinds.add_parser(
        "engine",
        help="in-process engine: one run, the 30-trial N = 6 experiment, the N = 3..30 sweep",
    )
    engine_parser.add_argument("--trials", type=at_least(1), default=30, help="trials per batch (default 30)")
    engine_parser.add_argument("--sweep", type=str, default="3-30", help="team sizes of the sweep, e.g. 3-30")
    engine_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    engine_parser.set_defaults(handler=run_engine_bench)

    emulator_parser = kinds.add_parser(
        "emulator",
        help="lockstep steps per second of a multi-process team over Zenoh, start-up, bytes per message, memory",
    )
    emulator_parser.add_argument("--robots", type=robot_list, default=[6], help="team size or list, e.g. 6,12,24")
    emulator_parser.add_argument("--steps", type=at_least(1), default=1000, help="steps per run (default 1000)")
    emulator_parser.add_argument("--strategy", choices=list(REGISTRY), default="self",
                                 help="communication strategy (default self)")
    emulator_parser.add_argument("--repeat", type=at_least(1), default=1,
                                 help="runs per configuration; medians reported")
    emulator_parser.add_argument("--robots-per-process", type=at_least(1), default=1, metavar="K",
                                 help="host K robots per process (each its own Zenoh participant)")
    emulator_parser.add_argument("--topology", choices=["mesh", "star"], help="as for spawn (default: by size)")
    emulator_parser.add_argument("--dashboard", choices=["off", "on", "compare"], default="off",
                                 help="draw the dashboard (to RUN_FOLDER/monitor.stdout), or alternate runs "
                                 "without and with it to measure what it costs")
    emulator_parser.add_argument("--secure", choices=["off", "on", "compare"], default="off",
                                 help="run secure teams (mutual TLS, access control; certificates made in a "
                                 "temporary folder), or alternate plain and secure runs to measure the cost; compare "
                                 "runs each team in a private network namespace when it can, to count the bytes "
                                 "on the wire")
    emulator_parser.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR",
                                 help="parent of the run folders (default runs)")
    emulator_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    emulator_parser.set_defaults(handler=run_emulator_bench)

    latency_parser = kinds.add_parser(
        "latency",
        help="neighbour round trip (request and reply between two robot processes): median, p99, CPU",
    )
    latency_parser.add_argument("--rounds", type=at_least(1), default=5000,
                                help="timed round trips (default 5000)")
    latency_parser.add_argument("--warmup", type=at_least(0), default=500,
                                help="untimed round trips first (default 500)")
    latency_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    latency_parser.set_defaults(handler=run_latency_bench)

    studies_parser = kinds.add_parser(
        "studies",
        help="studies: trials per second on 1 and every core, seconds per trial alone and batched, whole studies",
        description="Trials per second of stationary (N = 6) and moving (authors-moving, 1300 steps) studies on "
        "one worker and on every core; seconds per trial of a decentralized run alone and in batches of 10 and "
        "100; the decentralized/centralized cost; the wall time of the faults study (--drop 0,0.1,0.2,0.3,0.5, "
        "10 trials) and of the stationary sweep (N = 3..30, 30 trials, 2 strategies); the speed-up of 2 workers "
        "on a 100-trial study. Each beside its target.",
    )
    studies_parser.add_argument("--quick", action="store_true", help="small counts and few steps (a smoke test)")
    studies_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    studies_parser.set_defaults(handler=run_studies_bench)

    record_parser = kinds.add_parser(
        "record", help="what spawn --record FILE.mcap and --foxglove PORT cost a lockstep team: runs without and "
        "with each, in turn")
    record_parser.add_argument("--robots", type=at_least(2), default=6, help="team size (default 6)")
    record_parser.add_argument("--steps", type=at_least(1), default=1000, help="steps per run (default 1000)")
    record_parser.add_argument("--repeat", type=at_least(1), default=3, help="runs of each kind; medians (default 3)")
    record_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    record_parser.set_defaults(handler=run_record_bench)

    suite_parser = kinds.add_parser(
        "suite",
        help="engine, neighbour latency and the emulator for N = 6, 24, 64 and 256 (16 per process)",
    )
    suite_parser.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR",
                              help="parent of the run folders (default runs)")
    suite_parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the results as JSON")
    suite_parser.set_defaults(handler=run_suite)


def parse_range(text: str) -> list[int]:
    """``--sweep``: the team sizes of a sweep (:func:`tools.cli.options.team_sizes`)."""
    try:
        return team_sizes(text)
    except ValueError as error:
        raise UsageError(f"--sweep {text!r}: {error}") from None


def engine_table(results: dict, cores: object) -> Table:
    single, experiment, sweep = results["single_run"], results["experiment_n6"], results["sweep"]
    table = Table(title=f"engine ({cores} cores)")
    table.add_column("measurement")
    table.add_column("result", justify="right")
    table.add_row(f"one run, N = {single['robots']}", f"{single['steps_per_s']:.0f} steps/s")
    protocol = results["protocol_alone"]
    table.add_row(f"robot protocols alone, N = {protocol['robots']} (one process, no bus)",
                  f"{protocol['steps_per_s']:.0f} steps/s")
    for label, entry in ((f"experiment N = 6, {experiment['trials']} trials x 2 strategies", experiment),
                         (f"sweep N = {sweep['robots']}, {sweep['trials']} trials x 2", sweep)):
        table.add_row(label, f"{entry['wall_s']:.2f} s ({entry['converged']}/{entry['runs']} converged)")
    return table


def run_engine_bench(args: argparse.Namespace) -> int:
    results: dict[str, Any] = {"benchmark": "engine", "machine": machine(),
                               **engine_results(args.trials, parse_range(args.sweep))}
    show(engine_table(results, results["machine"]["cores"]))
    if args.json:
        write_json(args.json, results)
    return 0


def emulator_table(rows: list[dict], title: str) -> Table:
    compare = any("dashboard_cost" in row for row in rows)
    secure = any("security_cost" in row for row in rows)
    table = Table(title=title)
    columns = ["robots", "per process", "steps/s", "start-up s", *(f"{kind} B" for kind in MESSAGE_KINDS),
               "robot process MiB"]
    extra = (["with dashboard", "cost"] if compare else []) + (
        ["secure steps/s", "cost", "wire B/msg plain", "wire B/msg secure"] if secure else [])
    for column in columns + extra:
        table.add_column(column, justify="right")
    for row in rows:
        size = row["bytes_per_message"]
        table.add_row(
            str(row["robots"]),
            str(row["robots_per_process"]),
            f"{row['steps_per_s']:.0f}",
            f"{row['startup_s']:.1f}" if row["startup_s"] is not None else "-",
            *(f"{size.get(kind, 0):.1f}" for kind in MESSAGE_KINDS),
            f"{row['robot_process_rss_mib']:.1f}" if row["robot_process_rss_mib"] else "-",
            *([f"{row['steps_per_s_with_dashboard']:.0f}", f"{row['dashboard_cost']:+.1%}"] if compare else []),
            *(security_cells(row) if secure else []),
        )
    return table


def security_cells(row: dict) -> list[str]:
    wire = row.get("wire_bytes_per_message") or {}
    return [f"{row['steps_per_s_secure']:.0f}", f"{row['security_cost']:+.1%}",
            *(f"{wire[way]:.1f}" if way in wire else "-" for way in ("plain", "secure"))]


def run_emulator_bench(args: argparse.Namespace) -> int:
    try:
        rows = [emulator_row(robots, args.steps, args.strategy, args.repeat, args.dashboard, args.runs,
                             args.robots_per_process, args.topology, args.secure) for robots in args.robots]
    except BenchFailed as failure:
        err.print(str(failure), highlight=False)
        return 1
    results: dict[str, Any] = {"benchmark": "emulator", "machine": machine(), "strategy": args.strategy,
                                  "rows": rows}
    if len(rows) == 1:
        results["steps_per_s"] = rows[0]["steps_per_s"]
    cores = results["machine"]["cores"]
    show(emulator_table(rows, f"lockstep emulator ({cores} cores, {args.strategy} strategy)"))
    if args.json:
        write_json(args.json, results)
    return 0


def latency_table(result: dict, cores: object) -> Table:
    table = Table(title=f"neighbour round trip ({cores} cores, {result['rounds']} rounds)")
    for column in ("median us", "p99 us", "mean us", "CPU us requester", "CPU us responder"):
        table.add_column(column, justify="right")
    cpu = result["cpu_us_per_round_trip"]
    table.add_row(*(f"{value:.0f}" for value in (result["median_us"], result["p99_us"], result["mean_us"],
                                                 cpu["requester"], cpu["responder"])))
    return table


def run_latency_bench(args: argparse.Namespace) -> int:
    try:
        result = neighbour_round_trip(args.rounds, args.warmup)
    except BenchFailed as failure:
        err.print(str(failure), highlight=False)
        return 1
    results: dict[str, Any] = {"benchmark": "latency", "machine": machine(), **result}
    show(latency_table(result, results["machine"]["cores"]))
    if args.json:
        write_json(args.json, results)
    return 0


def ratios_table(ratios: dict[str, Any]) -> Table:
    table = Table(title=f"relative to this run's neighbour round trip ({ratios['round_trip_us']:.0f} us)")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for team, value in ratios["round_trips_per_step"].items():
        robots, per_process = team.split("x")
        table.add_row(f"round trips per lockstep step, {robots} robots, {per_process} per process", f"{value:.1f}")
    table.add_row("round trips per step of the 6 robot protocols alone (one process, no bus)",
                  f"{ratios['protocol_alone_round_trips_per_step']:.1f}")
    if "startup_64_s" in ratios:
        table.add_row("start-up of 64 x 1", f"{ratios['startup_64_s']:.1f} s")
    for per_process in (1, 16):
        key = f"robot_process_rss_mib_{per_process}_per_process"
        if key in ratios:
            table.add_row(f"robot process RSS, {per_process} per process", f"{ratios[key]:.1f} MiB")
    return table


def run_suite(args: argparse.Namespace) -> int:
    results: dict[str, Any] = {"benchmark": "suite", "machine": machine()}
    cores = results["machine"]["cores"]
    try:
        results["engine"] = engine_results(30, parse_range("3-30"))
        results["latency"] = neighbour_round_trip(5000, 500)
        results["emulator"] = [emulator_row(robots, steps, repeat=repeat, runs=args.runs,
                                            robots_per_process=per_process)
                               for robots, per_process, steps, repeat in SUITE_TEAMS]
    except BenchFailed as failure:
        err.print(str(failure), highlight=False)
        return 1
    show(engine_table(results["engine"], cores))
    show(latency_table(results["latency"], cores))
    show(emulator_table(results["emulator"], f"lockstep emulator ({cores} cores, self strategy)"))
    results["ratios"] = suite_ratios(results)
    show(ratios_table(results["ratios"]))
    if args.json:
        write_json(args.json, results)
    return 0


def studies_table(results: dict[str, Any]) -> Table:
    """Every measured value of ``bench studies`` beside its target (when it has one)."""
    cores = results["machine"]["cores"]
    table = Table(title=f"studies ({cores} cores, moving runs of {results['moving_steps']} steps)")
    for column, justify in (("measurement", "left"), ("value", "right"), ("target", "right"), ("met", "left")):
        table.add_column(column, justify=justify)  # type: ignore[arg-type]
    for name in THROUGHPUT:
        for workers, value in results["throughput_trials_per_s"][name].items():
            table.add_row(f"{name}, {workers.replace('_', ' ')}", f"{value:.2f} trials/s", "", "")
    met = targets_met(results)
    labels = {"alone_s_per_trial": "decentralized trial alone", "batch_10_s_per_trial": "... in a batch of 10",
              "batch_100_s_per_trial": "... in a batch of 100",
              "decentralized_over_centralized": "decentralized / centralized trial, alone",
              "faults_study_s": "faults study (5 drops, moving, every core)",
              "stationary_sweep_s": "stationary sweep (every core)",
              "workers_2_speedup": f"2 workers vs 1, {results['speedup_trials']} trials",
              "robot_start_s": "a robot from its fork to its first estimate"}
    for name, (way, target) in TARGETS.items():
        unit = " s" if name.endswith("_s") or name.endswith("per_trial") else " x"
        table.add_row(labels[name], f"{results[name]:.3f}{unit}", f"{way} {target:g}{unit}",
                      "yes" if met[name] else "no")
        if name == "decentralized_over_centralized":
            for label, ratio in results["decentralized_over_centralized_batched"].items():
                table.add_row(f"... per trial in a {label.replace('_', ' of ')}", f"{ratio:.3f} x", "", "")
        if name == "workers_2_speedup":
            table.add_row("... two processes at once vs one (the most 2 workers gain here)",
                          f"{results['two_process_ceiling']:.3f} x", "", "")
    return table


def run_studies_bench(args: argparse.Namespace) -> int:
    try:
        results = studies_results(QUICK if args.quick else FULL)
    except BenchFailed as failure:
        err.print(str(failure), highlight=False)
        return 1
    show(studies_table(results))
    if args.json:
        write_json(args.json, results)
    return 0


def run_record_bench(args: argparse.Namespace) -> int:
    require_sdk("bench record")
    result = {"machine": machine(), **record_cost(args.robots, args.steps, args.repeat)}
    table = Table(title=f"lockstep team of {result['robots']}, {result['steps']} steps, off / --record / "
                        f"--foxglove ({result['machine']['cores']} cores)")
    for column in ("", "steps/s", "cost", "budget"):
        table.add_column(column, justify="right")
    for variant, speed in result["steps_per_s"].items():
        cost = result["cost"].get(variant)
        table.add_row(variant, f"{speed:.0f}", "" if cost is None else f"{cost:+.1%}",
                      "" if cost is None else f"{result['budget']:.0%}")
    show(table)
    out.print(f"MCAP: {result['mcap_bytes_per_step'] or 0:.0f} B a step", highlight=False)
    if args.json:
        write_json(args.json, result)
    return 0
