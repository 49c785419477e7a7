"""``ringtrack experiment stationary|moving|faults|gates|tracking``: the paper's experiments and our sweeps, as
tables, JSON, CSV and figures."""

from __future__ import annotations

import argparse

from rich import box
from rich.table import Table

from ringtrack.agents.strategy import StrategyError, strategy_for
from ringtrack.tools.cli import experiment_faults, experiment_gates, experiment_nemesis, experiment_tracking
from ringtrack.tools.cli.options import (
    TEAM_SIZES_EXAMPLE,
    add_output_arguments,
    add_strategy_parameter_arguments,
    add_study_arguments,
    at_least,
    execution_of,
    overrides_named_by_flag,
    strategy_argument,
    strategy_parameters,
    team_sizes,
    write_study,
)
from ringtrack.tools.output.console import err, show
from ringtrack.tools.studies.experiment import (
    MOVING_COLUMNS,
    STATIONARY_BATCH,
    STATIONARY_COLUMNS,
    STRATEGIES,
    MovingStudy,
    StationaryStudy,
    moving_experiment,
    run_label,
    stationary_experiment,
)
from ringtrack.tools.studies.figures import moving_comparison, moving_velocities, stationary_comparison


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("experiment", help="run the paper's experiments")
    kinds = parser.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    stationary = kinds.add_parser(
        "stationary",
        help="constant vs self-triggered (or --strategies) on the same random starts (Ctime, Com-bar)",
        description="Run the strategies on the same seeded random starts (trial t uses seed S + t) "
        "and compare Ctime and Com-bar; --robots 3,6,10,20 (or 3-30, 3-30:3) sweeps team sizes; "
        "--strategies self,plan compares others (ratios against the first).",
    )
    stationary.add_argument("scenario", nargs="?", default="paper-stationary", help="base scenario")
    stationary.add_argument("--robots", type=robot_list, default=[6],
                            help=f"team size, list or range, e.g. {TEAM_SIZES_EXAMPLE}")
    stationary.add_argument("--strategies", type=strategy_list, default=list(STRATEGIES), metavar="A,B",
                            help="strategies to compare, registered names or .py files, the first the ratios' "
                            "baseline (default constant,self; e.g. self,plan)")
    add_strategy_parameter_arguments(stationary)
    stationary.add_argument("--trials", type=at_least(1), default=30, help="random starts per team size (default 30)")
    stationary.add_argument("--seed", type=at_least(0), default=0, help="seed of trial 0 (default 0)")
    stationary.add_argument("--sigma-deg", type=float, help="trigger tolerance sigma in degrees")
    stationary.add_argument("--law", choices=["prop", "deadbeat"], help="fresh-information law")
    stationary.add_argument("--steps", type=at_least(1), help="step limit per trial (default: control.max_steps)")
    add_output_arguments(stationary, json="write per-trial rows and means", plot="draw the comparison figure",
                         csv="write the per-trial rows as CSV (robots, strategy, trial, seed, Ctime, Com-bar, ...)")
    add_study_arguments(stationary, STATIONARY_BATCH)
    stationary.set_defaults(handler=run_stationary)

    moving = kinds.add_parser(
        "moving",
        help="moving target: constant/self-triggered with centralized/decentralized EKFs (Cerr, Terr)",
        description="The paper's moving-target comparison on a circling target: constant + centralized, "
        "self-triggered + centralized and self-triggered + decentralized at the scenario's circle (gazebo-moving: "
        "v = 1.0 m/s, w = 0.6 rad/s), then constant + centralized against self-triggered + decentralized at "
        "(v, w) = (0.6, 0.6), (1.0, 0.6), (1.0, 0.4), (1.0, 0.8). --plot PNG also writes PNG-velocities.png.",
    )
    moving.add_argument("scenario", nargs="?", default="gazebo-moving", help="base scenario (a circling target)")
    moving.add_argument("--trials", type=at_least(1), default=5, help="random starts per run (default 5)")
    moving.add_argument("--seed", type=at_least(0), default=0, help="seed of trial 0 (default 0)")
    moving.add_argument("--steps", type=at_least(1), help="steps per run (default: control.max_steps)")
    moving.add_argument("--settle", type=at_least(0), default=300,
                        help="means are taken from this step on (default 300)")
    moving.add_argument("--fusion", choices=["ci", "sequential"], help="decentralized fusion (default: scenario's)")
    moving.add_argument("--no-velocities", action="store_true", help="only the comparison at the scenario's circle")
    moving.add_argument("--strategies", type=strategy_list, metavar="A,B",
                        help="strategies to compare, each with a centralized and a decentralized EKF (one that needs "
                        "a mode: that one), e.g. self,belief (default: the paper's three runs)")
    add_output_arguments(moving, json="write the table and the Cerr/Terr series", plot="draw Cerr and Terr over time",
                         csv="write the per-trial rows as CSV (setting, strategy, estimation, trial, seed, Cerr and "
                         "Terr means, polls, messages, ...)")
    add_study_arguments(moving)
    moving.set_defaults(handler=run_moving)
    experiment_faults.register(kinds)
    experiment_gates.register(kinds)
    experiment_nemesis.register(kinds)
    experiment_tracking.register(kinds, strategy_list)


def strategy_list(text: str) -> list[str]:
    """Parse ``self,belief`` (registered names or .py files) into the strategies' scenario values."""
    values = [strategy_argument(part.strip()) or "" for part in text.split(",") if part.strip()]
    if not values:
        raise argparse.ArgumentTypeError(f"--strategies {text!r}: give names like self,belief")
    for value in values:
        try:
            strategy_for(value)
        except StrategyError as error:
            raise argparse.ArgumentTypeError(f"--strategies {text!r}: {error}") from None
    return values


def robot_list(text: str) -> list[int]:
    """``--robots``: team sizes (:func:`tools.cli.options.team_sizes`)."""
    try:
        return team_sizes(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"--robots {text!r}: {error}") from None


def run_stationary(args: argparse.Namespace) -> int:
    overrides = {"sigma_deg": args.sigma_deg, "law": args.law, "max_steps": args.steps,
                 "strategy_parameters": strategy_parameters(args)}
    with overrides_named_by_flag():
        result = stationary_experiment(args.scenario, args.robots, args.trials, args.seed, args.strategies,
                                       execution_of(args, args.json, args.csv), **overrides)
    show(results_table(result))
    write_study(args, result, stationary_comparison, result.rows, STATIONARY_COLUMNS)
    failed = [entry for entry in result.summary if entry.converged < entry.trials]
    for entry in failed:
        err.print(
            f"warning: {entry.trials - entry.converged} of {entry.trials} {entry.strategy} trials "
            f"with {entry.robots} robots did not converge within the step limit",
            highlight=False,
        )
    return 1 if failed else 0


def results_table(result: StationaryStudy) -> Table:
    """Mean +- std of Ctime and Com-bar per team size and strategy, with the ratios to the first
    strategy (by default self / constant)."""
    baseline = result.strategies[0]
    table = Table(title=f"stationary target, {result.trials} trials (seeds {result.seed}..), Ctime in steps, "
                  f"mean ± 1 sd; ÷: ratio to {baseline}", title_justify="left", box=box.SIMPLE_HEAD, pad_edge=False)
    for column in ("N", "strategy", "done", "Ctime", "Com-bar", "Ctime ÷", "Com ÷"):
        table.add_column(column, justify="right", no_wrap=True)
    ratios = {(entry.robots, entry.strategy): entry for entry in result.ratios}
    for entry in result.summary:
        ratio = ratios.get((entry.robots, entry.strategy))
        table.add_row(
            str(entry.robots),
            entry.strategy,
            f"{entry.converged}/{entry.trials}",
            _mean_std(entry.ctime_mean, entry.ctime_std, ".1f"),
            _mean_std(entry.com_bar_mean, entry.com_bar_std, ".3f"),
            f"{ratio.ctime_ratio:.3f}" if ratio else "",
            f"{ratio.com_bar_ratio:.3f}" if ratio else "",
        )
    return table


def _mean_std(mean: float | None, std: float | None, spec: str) -> str:
    return "-" if mean is None else f"{mean:{spec}} ± {std:{spec}}"


def run_moving(args: argparse.Namespace) -> int:
    result = moving_experiment(args.scenario, args.trials, args.seed, args.steps, args.settle,
                               velocities=not args.no_velocities, fusion=args.fusion, strategies=args.strategies,
                               execution=execution_of(args, args.json, args.csv))
    show(moving_table(result))
    write_study(args, result, moving_comparison, result.rows, MOVING_COLUMNS)
    if args.plot and not args.no_velocities:
        moving_velocities(result, args.plot.with_name(f"{args.plot.stem}-velocities{args.plot.suffix}"))
    return 0


def moving_table(result: MovingStudy) -> Table:
    """Means from step ``settle`` on, per run (the velocity setting equal to the main one is shown once)."""
    table = Table(title=f"moving target, {result.trials} trials, means from step {result.settle} of "
                  f"{result.steps}; ÷ central: Terr over the centralized reference's; msg and B: robot-to-robot "
                  "traffic (per step: over all steps)",
                  title_justify="left", box=box.SIMPLE_HEAD)
    for column in ("v, w", "strategy, EKF", "Cerr deg", "Terr m", "÷ central", "polls", "msg/step", "msg/rs",
                   "B/step"):
        table.add_column(column, justify="right", no_wrap=True)
    main = {(run.speed, run.angular_speed) for run in result.runs if run.group == "comparison"}
    for run in result.runs:
        if run.group == "velocities" and (run.speed, run.angular_speed) in main:
            continue
        table.add_row(
            f"{run.speed:g}, {run.angular_speed:g}",
            run_label(run.strategy, run.estimation),
            f"{run.cerr_mean_deg:.1f}",
            f"{run.terr_mean:.3f}",
            "-" if run.terr_ratio is None else f"{run.terr_ratio:.2f}",
            f"{run.poll_rate:.3f}",
            f"{run.robot_messages_per_step:.2f}",
            f"{run.robot_messages_per_robot_step:.3f}",
            f"{run.robot_bytes_per_step:.0f}",
        )
    return table
