"""``ringtrack simulate``: one run of a scenario in the in-process engine, summarised."""

from __future__ import annotations

import argparse
import statistics

from rich.table import Table

from ringtrack.agents import engine
from ringtrack.agents.summary import RunSummary, summarise
from ringtrack.tools.cli.options import (
    JSON_FILE,
    LOG_FILE,
    UNTIL_CONVERGED,
    add_from_step_argument,
    add_scenario_arguments,
    scenario_from_arguments,
    stops_at_convergence,
)
from ringtrack.tools.monitor.state import messages_saved
from ringtrack.tools.output.console import BUSIEST, SUMMARISED_ABOVE, show, warn_if_threshold_loose
from ringtrack.tools.output.files import write_json
from ringtrack.tools.runlog.log import write_engine_log


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "simulate",
        help="run a scenario in-process (no processes, no Zenoh) and summarise it",
        description="Run a scenario in the in-process engine. Without --steps a stationary target's run stops "
        "at convergence (at most control.max_steps steps) and a moving target's runs control.max_steps steps; "
        "with --steps K it runs exactly K steps.",
    )
    add_scenario_arguments(parser, steps_help=f"run exactly this many steps (default: {UNTIL_CONVERGED})")
    parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="write the summary as JSON")
    parser.add_argument("--log", type=LOG_FILE, metavar="PATH", help="write the run log (same format as spawn's)")
    add_from_step_argument(parser)
    parser.add_argument("--all-robots", action="store_true",
                        help="list every robot's polls (default: above 20 robots, min/median/max and the 5 busiest)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    scenario = scenario_from_arguments(args)
    warn_if_threshold_loose(scenario)
    history = engine.run(scenario, until_converged=stops_at_convergence(args, scenario),
                         record_positions=args.log is not None)
    result = summarise(history, settle=args.from_step)
    show(summary_table(result, args.all_robots))
    if args.json:
        write_json(args.json, result)
    if args.log:
        write_engine_log(args.log, history)
    return 0


SUMMARY_VALUE_WIDTH = 58  # columns of the summary's values, so that the table stays under 80


def summary_table(result: RunSummary, all_robots: bool = False) -> Table:
    """A two-column rich table of a run summary (under 80 columns). Polls per robot are listed for at
    most ``SUMMARISED_ABOVE`` robots (or with ``all_robots``), else summarised: min, median, max and
    the ``BUSIEST``."""
    robot_messages = result.robot_messages
    table = Table(title=f"{result.scenario}: {result.strategy} strategy", show_header=False)
    table.add_column(style="bold")
    table.add_column(max_width=SUMMARY_VALUE_WIDTH)  # prose: wraps rather than widening the table past 80
    ctime, triggers = result.ctime, result.triggers
    saved, share = messages_saved(result.robots, result.steps, robot_messages)
    rows = [
        ("robots", str(result.robots)),
        ("seed", str(result.seed)),
        ("steps run", str(result.steps)),
        ("converged", f"yes, Ctime = {ctime} steps" if ctime else "no"),
        ("Com-bar", f"{result.com_bar:.3f} polls per robot-step to Ctime (constant: 1)" if ctime else "-"),
        ("polls", f"{triggers.total}; per robot {polls_text(triggers.per_robot, all_robots)}"),
        ("robot-to-robot", f"{robot_messages} messages; {saved} saved ({share:.0%}) vs constant"),
        ("final Cerr", f"{_figure(result.cerr_final_deg, '.4f')} deg (true {result.cerr_true_final_deg:.4f} deg)"),
    ]
    if result.estimation != "known":
        settled = f" after step {result.from_step}" if result.from_step is not None else ""
        rows.append(("Terr", f"mean{settled} {_figure(result.terr_mean, '.3f')} m, final "
                             f"{result.terr_final:.3f} m ({result.estimation} estimation)"))
    if result.from_step is not None:
        rows.append(("Cerr", f"mean after step {result.from_step} {_figure(result.cerr_mean_deg, '.2f')} deg "
                             "(true)"))
    if result.energy is not None:
        team, per_robot = 1e3 * result.energy.team_j, [1e3 * j for j in result.energy.per_robot_j]
        rows.append(("radio energy", f"team {team:.3f} mJ, per robot {min(per_robot):.3f}-{max(per_robot):.3f} mJ"))
    for name, value in rows:
        table.add_row(name, value)
    return table


def _figure(value: float | None, spec: str) -> str:
    return "-" if value is None else f"{value:{spec}}"


def polls_text(per_robot: list[int], all_robots: bool) -> str:
    """Every robot's polls, or above ``SUMMARISED_ABOVE`` robots min/median/max and the busiest."""
    if all_robots or len(per_robot) <= SUMMARISED_ABOVE:
        return " ".join(map(str, per_robot))
    busiest = sorted(range(len(per_robot)), key=lambda robot: -per_robot[robot])[:BUSIEST]
    return (f"min {min(per_robot)}, median {statistics.median_low(per_robot)}, max {max(per_robot)}; busiest "
            + ", ".join(f"r{robot} {per_robot[robot]}" for robot in busiest) + " (--all-robots lists all)")
