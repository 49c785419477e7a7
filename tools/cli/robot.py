"""``ringtrack robot --id I``: one robot (or several, each its own participant) of a team."""

from __future__ import annotations

import argparse
import asyncio
import json
from pathlib import Path

from ringtrack.agents.process import run_robots
from ringtrack.bus.keys import robot_name
from ringtrack.tools.cli.options import positive, scenario_from_arguments
from ringtrack.tools.cli.role_flags import bus_config, common_flags, finished, robot_ids
from ringtrack.tools.output.console import UsageError


def register(commands: argparse._SubParsersAction) -> None:
    robot = commands.add_parser("robot", help="run one robot process")
    common_flags(robot)
    robot.add_argument("--id", type=robot_ids, required=True, metavar="I",
                       help="robot index 0..N-1 in counter-clockwise order; 0-7 or 0,2,4 runs several robots in "
                       "this process, each its own Zenoh participant")
    robot.add_argument("--reply-timeout", type=positive, metavar="S",
                       help="wall seconds a poll waits for replies (spawn: a step period in realtime, half the "
                       "--lockstep-wait in lockstep; default: wait)")
    robot.add_argument("--join", type=Path, metavar="RUN_FOLDER",
                       help="join the running team of a spawn run folder (scenario, run id, endpoints)")
    robot.set_defaults(handler=run_robot_role)


def run_robot_role(args: argparse.Namespace) -> int:
    if args.join is not None:
        join(args)
    scenario = scenario_from_arguments(args)
    for robot in args.id:
        if not 0 <= robot < scenario.robots:
            raise UsageError(f"--id {robot}: the team has robots 0..{scenario.robots - 1}")
    return finished("robot", asyncio.run(
        run_robots(args.id, scenario, args.run, bus_config(args, [robot_name(robot) for robot in args.id],
                                                           scenario.robots), args.monitor, args.exit_with_parent,
                   args.reply_timeout)
    ))


def join(args: argparse.Namespace) -> None:
    """Fill scenario, run id, endpoints and reply timeout from a spawn run folder."""
    run_file = args.join / "run.json"
    if not run_file.is_file():
        raise UsageError(f"--join {args.join}: no run.json there; give the folder of a running spawn")
    run = json.loads(run_file.read_text())
    args.scenario = str(args.join / "scenario.toml")
    args.run = int(run["run"], 16)
    args.connect = run["connect"]
    args.monitor = True
    if args.secure is None and run.get("secure"):
        args.secure = Path(run["secure"])
    if args.reply_timeout is None:
        args.reply_timeout = run["reply_timeout"]
    args.lease = run.get("lease_s", args.lease)
