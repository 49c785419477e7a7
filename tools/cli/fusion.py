"""``ringtrack fusion``: the fusion centre of a team's centralized estimation."""

from __future__ import annotations

import argparse
import asyncio

from ringtrack.agents.centre import run_fusion
from ringtrack.bus.keys import FUSION
from ringtrack.tools.cli.options import scenario_from_arguments
from ringtrack.tools.cli.role_flags import bus_config, common_flags, finished
from ringtrack.tools.output.console import UsageError


def register(commands: argparse._SubParsersAction) -> None:
    fusion = commands.add_parser("fusion", help="run the fusion centre of centralized estimation")
    common_flags(fusion)
    fusion.set_defaults(handler=run_fusion_role)


def run_fusion_role(args: argparse.Namespace) -> int:
    scenario = scenario_from_arguments(args)
    if scenario.estimation.mode != "centralized":
        raise UsageError(f"the scenario's estimation.mode is {scenario.estimation.mode!r}; a fusion centre serves "
                         "only 'centralized'")
    return finished("fusion", asyncio.run(
        run_fusion(scenario, args.run, bus_config(args, [FUSION], scenario.robots), args.monitor,
                   args.exit_with_parent)))
