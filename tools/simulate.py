"""``ringtrack simulate``: one run of a scenario in the in-process engine, summarised."""

from __future__ import annotations

import argparse

from rich.table import Table

from ringtrack.agents import engine
from ringtrack.tools.console import out, write_json
from ringtrack.tools.options import JSON_FILE, LOG_FILE, add_scenario_arguments, scenario_from_arguments
from ringtrack.tools.runlog import write_engine_log


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "simulate",
        help="run a scenario in-process (no processes, no Zenoh) and summarise it",
        description="Run a scenario in the in-process engine. Without --steps it stops at convergence "
        "(at most control.max_steps steps); with --steps K it runs exactly K steps.",
    )
    add_scenario_arguments(parser, steps_help="run exactly this many steps")
    parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="write the summary as JSON")
    parser.add_argument("--log", type=LOG_FILE, metavar="PATH", help="write the run log (same format as spawn's)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    scenario = scenario_from_arguments(args)
    history = engine.run(scenario, until_converged=args.steps is None, record_positions=args.log is not None)
    result = engine.summary(history)
    out.print(summary_table(result))
    if args.json:
        write_json(args.json, result)
    if args.log:
        write_engine_log(args.log, history)
    return 0


def summary_table(result: dict) -> Table:
    """A two-column rich table of a run summary."""
    table = Table(title=f"{result['scenario']}: {result['strategy']} strategy", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    ctime = result["ctime"]
    rows = [
        ("robots", str(result["robots"])),
        ("seed", str(result["seed"])),
        ("steps run", str(result["steps"])),
        ("converged", f"yes, Ctime = {ctime} steps" if ctime else "no"),
        ("Com-bar", f"{result['com_bar']:.3f}" if ctime else "-"),
        ("triggers", f"{result['triggers']['total']}  per robot {result['triggers']['per_robot']}"),
        ("final Cerr", f"{result['cerr_final_deg']:.4f} deg (true {result['cerr_true_final_deg']:.4f} deg)"),
    ]
    if result["estimation"] != "known":
        rows.append(("Terr", f"mean {result['terr_mean']:.3f} m, final {result['terr_final']:.3f} m "
                             f"({result['estimation']} estimation)"))
    if "energy" in result:
        team, per_robot = 1e3 * result["energy"]["team_j"], [1e3 * j for j in result["energy"]["per_robot_j"]]
        rows.append(("radio energy", f"team {team:.3f} mJ, per robot {min(per_robot):.3f}-{max(per_robot):.3f} mJ"))
    for name, value in rows:
        table.add_row(name, value)
    return table
