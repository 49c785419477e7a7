"""The ``ringtrack`` command: argument parsing and dispatch, one module per command.

Each module of this package registers its commands (:data:`COMMANDS` says which) and turns their
flags into calls of the rooms beside it (``tools.team``, ``tools.studies``, ...). A command's module
is imported by name when the parser is built, and only the module of the command given: ``ringtrack
robot`` does not import the dashboard, plotting or benchmark code, and ``ringtrack spawn`` draws its
first frame before the study code would have loaded. ``ringtrack --help`` and an unknown command
build the whole parser. This is the one place where project modules are imported at call time.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import signal
import sys
from collections.abc import Sequence
from importlib import metadata
from typing import NoReturn

# Module of tools/cli -> the commands its register() adds (tests/test_help.py checks the two agree).
COMMANDS: dict[str, tuple[str, ...]] = {
    "simulate": ("simulate",),
    "spawn": ("spawn",),
    "world": ("world",),
    "robot": ("robot",),
    "router": ("router",),
    "fusion": ("fusion",),
    "monitor": ("monitor",),
    "replay": ("replay",),
    "plot": ("plot",),
    "check": ("check",),
    "experiment": ("experiment",),
    "bench": ("bench",),
    "certs": ("certs",),
    "introspect": ("list", "echo", "hz"),
    "export": ("export",),
    "strategies": ("strategies",),
    "scenarios": ("scenarios",),
}

# One-line errors of bad input: (module, class). A class whose module was never imported cannot
# have been raised, so none is imported just to be caught.
USER_ERRORS = (
    ("ringtrack.world.scenario_errors", "ScenarioError"),
    ("ringtrack.world.geometry", "RegionError"),
    ("ringtrack.tools.output.console", "UsageError"),
    ("ringtrack.tools.output.files", "OutputError"),
    ("ringtrack.bus.config", "BusError"),
    ("ringtrack.bus.identity", "IdCollision"),
    ("ringtrack.bus.lives", "Superseded"),
    ("ringtrack.bus.lives", "NoLife"),
    ("ringtrack.tools.runlog.log", "LogError"),
    ("ringtrack.tools.studies.study", "StudyStopped"),
)


class Parser(argparse.ArgumentParser):
    """Reports a bad flag in one line naming it, and where to read more, instead of the usage text."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"ringtrack: error: {message} (see '{self.prog} --help')\n")


def modules_for(argv: Sequence[str], modules: Sequence[str]) -> list[str]:
    """The one module of ``modules`` that registers the command ``argv`` starts with, or all of them
    when it starts with none of theirs (``--help``, a typo, nothing)."""
    named = [module for module in modules if argv and argv[0] in COMMANDS[module]]
    return named or list(modules)


def version() -> str:
    """The installed distribution's version (``ringtrack --version``)."""
    try:
        return metadata.version("ringtrack")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


def build_parser(commands: Sequence[str] = tuple(COMMANDS)) -> argparse.ArgumentParser:
    """The whole command line, or the part of it that the modules ``commands`` register."""
    parser = Parser(
        prog="ringtrack",
        description="Self-triggered multi-robot target tracking: engine, emulator over Zenoh, experiments.",
    )
    parser.add_argument("--version", action="version", version=f"ringtrack {version()}")
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        importlib.import_module(f"ringtrack.tools.cli.{name}").register(subcommands)
    return parser


def main(argv: Sequence[str] | None = None, commands: Sequence[str] = tuple(COMMANDS)) -> int:
    """Entry point of the console script; returns the process exit code."""
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(modules_for(argv, commands)).parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        return int(args.handler(args) or 0)
    except ValueError as error:
        user_errors = tuple(getattr(sys.modules[module], name) for module, name in USER_ERRORS if module in sys.modules)
        if not isinstance(error, user_errors):
            raise
        print(f"ringtrack: error: {error}", file=sys.stderr)
        return getattr(error, "exit_code", 2)
    except KeyboardInterrupt:
        print("ringtrack: interrupted", file=sys.stderr)
        return 130
    except Exception as error:
        terminated = getattr(sys.modules.get("ringtrack.tools.team.supervisor"), "Terminated", ())
        if not isinstance(error, terminated):
            raise
        print("ringtrack: terminated (SIGTERM)", file=sys.stderr)
        return 128 + signal.SIGTERM
