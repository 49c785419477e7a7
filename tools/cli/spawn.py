"""``ringtrack spawn``: a whole team as separate processes over Zenoh (see :mod:`tools.team.spawn`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.bus.config import LEASE_S
from ringtrack.bus.keys import robot_index
from ringtrack.tools.cli.monitor import add_foxglove_arguments, check_foxglove_arguments
from ringtrack.tools.cli.options import (
    JSON_FILE,
    LOG_FILE,
    UNTIL_CONVERGED,
    add_from_step_argument,
    add_scenario_arguments,
    at_least,
    positive,
    scenario_from_arguments,
    stops_at_convergence,
)
from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.output.files import write_json
from ringtrack.tools.team.nemesis import EXAMPLE, parse_plan
from ringtrack.tools.team.plan import LOCKSTEP_WAIT_S, TeamPlan, TeamResult
from ringtrack.tools.team.spawn import MESH_LIMIT, spawn_team


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "spawn",
        help="run a team: world, robots and monitor as separate processes over Zenoh",
        description="Start the world, one process per robot and the monitor over Zenoh (loopback, free "
        "ports), show progress, and stop everything on completion, Ctrl-C or SIGTERM.",
    )
    add_scenario_arguments(parser, steps_help=f"run exactly this many steps (default: {UNTIL_CONVERGED})")
    parser.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                        help="lockstep: each step waits for every robot (deterministic, equals the engine); "
                        "realtime: a step every dt / rate wall seconds (default lockstep)")
    parser.add_argument("--rate", type=positive, default=1.0, help="realtime: simulated seconds per wall second")
    parser.add_argument("--lockstep-wait", type=positive, default=LOCKSTEP_WAIT_S, metavar="S",
                        help="lockstep: a robot silent this many seconds in one step is treated as gone, and a poll "
                        f"gives up on a reply after half of it (default {LOCKSTEP_WAIT_S:g})")
    parser.add_argument("--lease", type=positive, default=LEASE_S, metavar="S",
                        help="liveliness lease of every process: one silent this many seconds (frozen, cut off) is "
                        f"seen gone by the others (default {LEASE_S:g})")
    parser.add_argument("--log", type=LOG_FILE, metavar="PATH", help="run log path (default: RUN_FOLDER/log.jsonl)")
    parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="also write the summary JSON here")
    parser.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR", help="parent of run folders")
    parser.add_argument("--robots-per-process", type=at_least(1), default=1, metavar="K",
                        help="host K robots per process, each still its own Zenoh participant (large teams)")
    parser.add_argument("--topology", choices=["mesh", "star"],
                        help=f"mesh: every pair linked; star: the world is a Zenoh router (default: mesh up to "
                        f"{MESH_LIMIT} participants)")
    parser.add_argument("--secure", type=Path, metavar="DIR",
                        help="team folder made by ringtrack certs: mutual TLS on every link and access control")
    display = parser.add_mutually_exclusive_group()
    display.add_argument("--dashboard", action="store_true",
                         help="draw the live dashboard even without a terminal (the default on a terminal)")
    display.add_argument("--no-dashboard", action="store_true", help="plain summary lines instead of the dashboard")
    add_from_step_argument(parser)
    parser.add_argument("--all-robots", action="store_true",
                        help="list every robot and link in the end-of-run report (default: above 20, "
                        "min/median/max and the 5 busiest)")
    parser.add_argument("--start", choices=["fork", "exec"],
                        help="fork: robot processes are forked from one launcher that has imported their code (a "
                        "fast start-up; Linux); exec: each is a fresh interpreter (default: fork where it works)")
    parser.add_argument("--audit", action="store_true",
                        help="the monitor receives a copy of every message and counts it itself (an independent "
                        "tally); by default, in lockstep, it takes measurements and commands by the world's own "
                        "counts and robot-to-robot messages by the robots' own, from the world's digests, and "
                        "observes the rest")
    parser.add_argument("--nemesis", metavar="PLAN",
                        help="process faults against the live team, in wall seconds after its first step: "
                        f"'{EXAMPLE}' (kill, restart a robot as its next life, pause for a time), or a TOML file "
                        "with [nemesis] faults = [...]; what was done is written to nemesis.jsonl and the summary")
    add_foxglove_arguments(parser)
    parser.set_defaults(handler=run_spawn)


def run_spawn(args: argparse.Namespace) -> int:
    check_foxglove_arguments(args)
    scenario = scenario_from_arguments(args)
    faults = [] if args.nemesis is None else parse_plan(args.nemesis, scenario.robots)
    if args.robots_per_process > 1 and any(robot_index(fault.target) is not None for fault in faults):
        raise UsageError("--nemesis: faults against robots need one robot per process; drop --robots-per-process")
    plan = TeamPlan(
        scenario=scenario,
        clock=args.clock,
        rate=args.rate,
        runs=args.runs,
        log_path=args.log,
        dashboard=True if args.dashboard else False if args.no_dashboard else None,
        until_converged=stops_at_convergence(args, scenario),
        topology=args.topology,
        robots_per_process=args.robots_per_process,
        secure=args.secure,
        all_robots=args.all_robots,
        lockstep_wait=args.lockstep_wait,
        lease=args.lease,
        audit=args.audit,
        settle=args.from_step,
        start=args.start,
        foxglove=args.foxglove,
        record=args.record,
        nemesis=faults,
    )
    result = spawn_team(plan)
    if args.json:
        write_json(args.json, result)
    out.print(summary_line(result), highlight=False, soft_wrap=True)
    return result.exit_code


def summary_line(result: TeamResult) -> str:
    """Speed and run folder (the monitor's report above it gives Ctime, Com-bar and the traffic)."""
    outcome = result.outcome
    if outcome is None:
        return f"spawn: run folder {result.folder}"
    speed = f" at {result.steps_per_s:.0f} steps/s" if result.steps_per_s else ""
    line = f"spawn: {outcome.steps} steps{speed}"
    if result.distrust:
        line += f"; not trusted: {result.distrust}"
    elif result.monitor_lost:  # no monitor's report above: say what the senders counted
        converged = f"converged at step {outcome.ctime}" if outcome.converged else "did not converge"
        if result.uncounted:  # a sender that left no counts (killed, or a full disk): the total is not known
            line += (f"; {converged}; robot-to-robot messages unknown (the monitor was lost and "
                     f"{', '.join(result.uncounted)} left no counts)")
        else:
            line += (f"; {converged}; robot-to-robot messages {result.messages.get('robot', 0)} (the senders' counts: "
                     "the monitor was lost)")
    return f"{line}\nrun folder: {result.folder}"
