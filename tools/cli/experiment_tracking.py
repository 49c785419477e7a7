"""``ringtrack experiment tracking``: decentralized tracking against the centralized filter and the
posterior Cramér-Rao bound over many scenarios (:mod:`tools.studies.tracking`)."""

from __future__ import annotations

import argparse

from rich import box
from rich.table import Table

from ringtrack.tools.cli.options import (
    add_output_arguments,
    add_study_arguments,
    at_least,
    execution_of,
    write_study,
)
from ringtrack.tools.output.console import show
from ringtrack.tools.studies.experiment import run_label
from ringtrack.tools.studies.tracking import (
    CERR_GOAL_DEG,
    SETTLE,
    TERR_GOAL,
    TRACKING_COLUMNS,
    TrackingStudy,
    TrackingVerdict,
    decentralized_strategies,
    plot_tracking,
    tracking_experiment,
)


def register(kinds: argparse._SubParsersAction, strategy_list: argparse._ActionType) -> None:
    parser = kinds.add_parser(
        "tracking",
        help="decentralized tracking vs the centralized EKF (Terr ratio) and the PCRB over many scenarios",
        description="On every scenario (shipped names, TOML files, folders of them such as ringtrack scenarios "
        "generate writes), run each strategy with decentralized estimation and, as reference, the scenario's "
        "own strategy (self where it needs decentralized estimation) with the centralized EKF, on the same "
        "seeds (trial t: seed S + t; the same starts, target paths and noise). Reports settled Terr, its ratio "
        "to the centralized Terr, Cerr, messages per robot-step and the RMSE of the robots' estimates; where "
        "the target is a random walk, the posterior Cramér-Rao bound along each trial's path (docs/algorithms.md "
        "section 19).",
    )
    parser.add_argument("scenarios", nargs="*", default=["authors-moving"], metavar="SCENARIO",
                        help="shipped names, TOML files or folders of TOML files (default authors-moving)")
    parser.add_argument("--strategies", type=strategy_list, metavar="A,B",
                        help="strategies run with decentralized estimation, registered names or .py files (default: "
                        f"every registered one that can, {','.join(decentralized_strategies())})")
    parser.add_argument("--trials", type=at_least(1), default=5, help="random starts per run (default 5)")
    parser.add_argument("--seed", type=at_least(0), default=0, help="seed of trial 0 (default 0)")
    parser.add_argument("--steps", type=at_least(2), help="steps per run (default: each scenario's control.max_steps)")
    parser.add_argument("--settle", type=at_least(0),
                        help=f"means are taken from this step on (default {SETTLE}, or the last step of a shorter run)")
    add_output_arguments(parser, json="write the rows and the study's settings", csv="write the rows as CSV",
                         plot="draw Terr / centralized Terr against messages per robot-step")
    add_study_arguments(parser)
    parser.set_defaults(handler=run_tracking)


def run_tracking(args: argparse.Namespace) -> int:
    result = tracking_experiment(args.scenarios, args.trials, args.seed, args.strategies, args.steps, args.settle,
                                 execution_of(args, args.json, args.csv))
    show(tracking_table(result))
    for verdict in result.verdicts:
        show(verdict_line(verdict, result.labels[verdict.strategy]))
    write_study(args, result, plot_tracking, result.rows, TRACKING_COLUMNS)
    return 0


def _figure(value: float | None, spec: str) -> str:
    return "-" if value is None else f"{value:{spec}}"


def tracking_table(result: TrackingStudy) -> Table:
    """A row per scenario and run: settled Terr, its ratio to the centralized, Cerr, messages per
    robot-step, RMSE and (random walks) the bound."""
    table = Table(title=f"tracking, {result.trials} trials (seeds {result.seed}..), means from step {result.settle} "
                  "(or a shorter run's last); ÷ central: Terr over the centralized EKF's; CRB: posterior Cramér-Rao "
                  "bound (RMSE, m)", title_justify="left", box=box.SIMPLE_HEAD)
    for column in ("scenario", "target", "N", "strategy, EKF", "Terr m", "÷ central", "Cerr deg", "msg/rs",
                   "RMSE m", "CRB m", "RMSE ÷ CRB"):
        table.add_column(column, justify="right", no_wrap=True)
    for row in result.rows:
        table.add_row(row.scenario, row.motion, str(row.robots), run_label(row.strategy, row.estimation),
                      _figure(row.terr_mean, ".3f"), _figure(row.terr_ratio, ".2f"), _figure(row.cerr_mean_deg, ".1f"),
                      f"{row.robot_messages_per_robot_step:.3f}", _figure(row.rmse, ".3f"),
                      _figure(row.crb_rmse, ".3f"), _figure(row.rmse_over_crb, ".2f"))
    return table


def verdict_line(verdict: TrackingVerdict, label: str) -> str:
    """One line on how a decentralized strategy fared against the centralized filter."""
    return (f"{label}: Terr <= {TERR_GOAL}x centralized on no more messages on {verdict.met} of {verdict.scenarios} "
            f"scenarios, true Cerr within {CERR_GOAL_DEG:g} deg on {verdict.cerr_met}; worst Terr "
            f"{_worst(verdict.worst_terr_ratio, '.2f', 'x', verdict.worst_terr_scenario)}, messages "
            f"{_worst(verdict.worst_message_ratio, '.2f', 'x', verdict.worst_message_scenario)}, Cerr "
            f"{_worst(verdict.worst_cerr_excess_deg, '+.2f', ' deg', verdict.worst_cerr_scenario)}")


def _worst(value: float | None, spec: str, unit: str, scenario: str) -> str:
    """A verdict's worst figure and where it was, e.g. ``1.34x (gazebo-moving)``; ``unknown`` where no
    scenario had it (a ratio to a centralized Terr of 0, a mean of no settled step)."""
    return "unknown" if value is None else f"{value:{spec}}{unit} ({scenario})"
