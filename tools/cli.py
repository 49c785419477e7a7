"""The ``ringtrack`` command: one sub-command per module, bad input answered in one line, exit 2."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from tools import bench, check, experiment, plot, replay, roles, simulate, spawn
from tools.console import UsageError, err
from bus.config import BusError
from tools.runlog import LogError
from world.geometry import RegionError
from world.scenario import ScenarioError

COMMANDS = (simulate, spawn, roles, replay, plot, check, experiment, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ringtrack",
        description="Self-triggered multi-robot target tracking: engine, emulator over Zenoh, experiments.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        return int(args.handler(args) or 0)
    except (ScenarioError, RegionError, UsageError, BusError, LogError) as error:
        err.print(f"ringtrack: error: {error}", highlight=False, markup=False)
        return 2
    except KeyboardInterrupt:
        err.print("ringtrack: interrupted", highlight=False)
        return 130


if __name__ == "__main__":
    sys.exit(main())
