"""``ringtrack world``: the world process of a team (motion, noisy ranges, the clock)."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path

from ringtrack.agents.strategy import check_strategy
from ringtrack.bus.keys import WORLD
from ringtrack.tools.cli.options import positive, scenario_from_arguments, stops_at_convergence
from ringtrack.tools.cli.role_flags import bus_config, common_flags, digests
from ringtrack.tools.output.console import warn_if_threshold_loose
from ringtrack.world.process import WorldOptions, run_world


def register(commands: argparse._SubParsersAction) -> None:
    world = commands.add_parser("world", help="run the world process of a team")
    common_flags(world)
    world.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                       help="lockstep: wait for every robot each step; realtime: a step every dt / rate wall "
                       "seconds (default lockstep)")
    world.add_argument("--rate", type=positive, default=1.0, help="realtime: simulated seconds per wall second")
    world.add_argument("--lockstep-wait", type=positive, default=10.0, metavar="S",
                       help="lockstep: treat a robot silent this many seconds in one step as gone (default 10)")
    world.add_argument("--monitor-grace", type=positive, default=None, metavar="S",
                       help="with --monitor: when the monitor goes away, hold the run up to S seconds for a monitor "
                       "resuming its log (monitor --resume) instead of ending it (default: end it)")
    world.add_argument("--announce", type=Path, metavar="PATH",
                       help="write the endpoints the world listens on to PATH (JSON)")
    world.set_defaults(handler=run_world_role)


def run_world_role(args: argparse.Namespace) -> int:
    scenario = scenario_from_arguments(args)
    warn_if_threshold_loose(scenario)
    options = WorldOptions(
        steps=scenario.max_steps,
        clock=args.clock,
        rate=args.rate,
        expect_monitor=args.monitor,
        announce=args.announce,
        until_converged=stops_at_convergence(args, scenario),  # as spawn and simulate
        lockstep_wait=args.lockstep_wait,
        digest=args.monitor and digests(args),
        cerr=check_strategy(scenario).cerr,
        monitor_grace=args.monitor_grace or 0.0,
    )
    config = bus_config(args, [WORLD], scenario.robots, admin_space=args.announce is not None)
    return asyncio.run(run_world(scenario, scenario.seed, args.run, config, options, args.exit_with_parent))
