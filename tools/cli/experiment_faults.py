"""``ringtrack experiment faults``: Cerr, Terr, Ctime and energy against drop rate, partitions and range."""

from __future__ import annotations

import argparse
import itertools
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np
from rich import box
from rich.table import Table

from ringtrack.tools.cli.options import (
    add_output_arguments,
    add_study_arguments,
    at_least,
    execution_of,
    write_study,
)
from ringtrack.tools.output.console import UsageError, err, show
from ringtrack.tools.studies.figures import robustness_curves
from ringtrack.tools.studies.robustness import (
    OUTAGE_START,
    STRATEGIES,
    Cell,
    FaultStudy,
    FaultSummary,
    Verification,
    _run_label,
    base_spec,
    cell_scenario,
    faults_experiment,
    summary_columns,
    verify,
)


def register(kinds: argparse._SubParsersAction) -> None:
    parser = kinds.add_parser(
        "faults",
        help="robustness curves: Ctime, Com-bar, messages, energy (Cerr, Terr) against drop, outage, range",
        description="Sweep the drop rate (--drop), a partition outage's length (--outage-steps) and the "
        "communication range (--communication-range) in the in-process engine, for both strategies (and "
        "each estimation mode of a moving target) on the same seeded random starts; mean and sd over the "
        "trials of every cell. --verify K re-runs K runs chosen by the seed as lockstep teams over Zenoh "
        "and checks they equal the engine.",
    )
    parser.add_argument("scenario", nargs="?", default="paper-stationary", help="base scenario")
    parser.add_argument("--drop", type=number_list("--drop", probability), default=[0.0],
                        help="drop probabilities, e.g. 0,0.1,0.2,0.3,0.5 (default 0)")
    parser.add_argument("--outage-steps", type=number_list("--outage-steps", steps_count), default=[0],
                        help=f"lengths (steps) of a partition from step {OUTAGE_START}, e.g. 0,100,200 (default 0)")
    parser.add_argument("--communication-range", type=number_list("--communication-range", metres), default=None,
                        help="r_c values in metres, 'none' for unlimited, e.g. none,8,6 (default: the scenario's)")
    parser.add_argument("--trials", type=at_least(1), default=30, help="random starts per cell (default 30)")
    parser.add_argument("--seed", type=at_least(0), default=0, help="seed of trial 0 (default 0)")
    parser.add_argument("--steps", type=at_least(1), help="step limit per run (default: control.max_steps)")
    parser.add_argument("--settle", type=at_least(0), default=300,
                        help="moving target: Cerr and Terr are averaged from this step on (default 300)")
    parser.add_argument("--verify", type=at_least(0), default=0, metavar="K",
                        help="re-run K runs as lockstep teams over Zenoh and check they equal the engine")
    add_output_arguments(parser, json="write the summary, per-trial rows, checks",
                         csv="write the summary rows as CSV",
                         plot="draw every quantity against the swept one (error bars: +-1 sd)")
    add_study_arguments(parser)
    parser.set_defaults(handler=run_faults)


# ---------------------------------------------------------------------------- flags
def probability(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise ValueError
    return value


def steps_count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise ValueError
    return value


def metres(text: str) -> float | None:
    if text.strip().lower() in ("none", "inf", "unlimited"):
        return None
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise ValueError
    return value


def number_list(flag: str, parse: Callable[[str], object]) -> Callable[[str], list]:
    """An argparse type: comma-separated values, each checked by ``parse``."""

    def parse_list(text: str) -> list:
        try:
            values = [parse(part.strip()) for part in text.split(",") if part.strip()]
        except ValueError:
            values = []
        if not values:
            raise argparse.ArgumentTypeError(f"{flag} {text!r}: give comma-separated values like "
                                             + {"--drop": "0,0.1,0.5 (probabilities)",
                                                "--outage-steps": "0,100,200 (steps >= 0)",
                                                "--communication-range": "none,8,6 (metres > 0)"}[flag])
        return values

    parse_list.__name__ = flag
    return parse_list


# ---------------------------------------------------------------------------- command
def run_faults(args: argparse.Namespace) -> int:
    spec, label = base_spec(args.scenario)
    ranges = args.communication_range or [spec.limits.communication_range]
    cells = [Cell(*values) for values in itertools.product(args.drop, args.outage_steps, ranges)]
    probe = cell_scenario(spec, label, cells[0], STRATEGIES[0], None, args.steps)  # flags checked before any work
    if max(args.outage_steps) and probe.robots < 4:
        raise UsageError("--outage-steps: a partition needs at least 4 robots")
    result = faults_experiment(args.scenario, cells, args.trials, args.seed, args.steps, args.settle,
                               execution=execution_of(args, args.json, args.csv))
    show(faults_table(result))
    code = 0
    if args.verify:
        with tempfile.TemporaryDirectory(prefix="ringtrack-verify-") as folder:
            err.print(f"verifying {args.verify} runs as lockstep teams over Zenoh ...", highlight=False)
            started = time.perf_counter()
            checks = verify(args.scenario, cells, args.trials, args.verify, args.seed, args.steps, Path(folder))
        verified = Verification(requested=args.verify, wall_s=time.perf_counter() - started,
                                all_equal=all(check.equal for check in checks), runs=checks)
        result = msgspec.structs.replace(result, verify=verified)
        for check in checks:
            err.print(f"verify {_run_label(cells[check.cell], check.strategy, check.estimation)} trial "
                      f"{check.trial} (seed {check.seed}, {check.steps} steps): "
                      + ("equal to the engine" if check.equal else f"DIFFERS {msgspec.to_builtins(check)}"),
                      highlight=False)
        code = 0 if verified.all_equal else 1
    write_study(args, result, robustness_curves, result.summary, summary_columns(result))
    return code


def faults_table(result: FaultStudy) -> Table:
    """Mean +- sd per cell and variant."""
    moving = result.moving
    table = Table(title=f"{result.scenario}: {result.trials} trials per cell (seeds {result.seed}..), "
                  f"mean ± sd; {result.costs_span}" + (f", Cerr/Terr from step {result.settle}" if moving else ""),
                  title_justify="left", box=box.SIMPLE_HEAD)
    headers = ["drop", "outage", "r_c", "strategy", "done", "Ctime", "Com-bar", "msgs", "J/robot"]
    headers += ["Cerr deg", "Terr m"] if moving else []
    for column in headers:
        table.add_column(column, justify="right", no_wrap=True)
    for entry in result.summary:
        reach = "-" if entry.communication_range is None else f"{entry.communication_range:g}"
        strategy = entry.strategy + (f"+{entry.estimation[:7]}" if moving else "")
        cells = [f"{entry.drop:g}", str(entry.outage_steps), reach, strategy,
                 f"{entry.converged_mean:.0%}",
                 _mean_sd(entry, "ctime", ".0f"), _mean_sd(entry, "com_bar", ".3f"),
                 _mean_sd(entry, "messages", ".0f"), _mean_sd(entry, "energy_per_robot", ".2e")]
        cells += [_mean_sd(entry, "cerr", ".2f"), _mean_sd(entry, "terr", ".3f")] if moving else []
        table.add_row(*cells)
    return table


def _mean_sd(entry: FaultSummary, metric: str, spec: str) -> str:
    mean, sd = entry.mean(metric), entry.sd(metric)
    return "-" if mean is None else f"{mean:{spec}} ± {sd:{spec}}"
