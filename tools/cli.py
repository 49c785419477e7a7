"""The ``ringtrack`` command: one sub-command per module, bad input answered in one line, exit 2.

Command modules are imported by name when the parser is built, and only the module of the command
given (:data:`COMMANDS` says which module registers which command): ``ringtrack spawn`` does not
import plotting, benchmark or introspection code before its first frame, and ``python -m
ringtrack.tools.roles`` builds a parser with the role commands only. ``ringtrack --help`` and an
unknown command build the whole parser.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence
from typing import NoReturn

# Module of tools/ -> the commands its register() adds (tests/test_help.py checks the two agree).
COMMANDS: dict[str, tuple[str, ...]] = {
    "simulate": ("simulate",),
    "spawn": ("spawn",),
    "roles": ("world", "robot", "router", "fusion", "monitor"),
    "replay": ("replay",),
    "plot": ("plot",),
    "check": ("check",),
    "experiment": ("experiment",),
    "bench": ("bench",),
    "certs": ("certs",),
    "introspect": ("list", "echo", "hz"),
    "export": ("export",),
    "strategies": ("strategies",),
}

# One-line errors of bad input: (module, class). A class whose module was never imported cannot
# have been raised, so none is imported just to be caught.
USER_ERRORS = (
    ("ringtrack.world.scenario_errors", "ScenarioError"),
    ("ringtrack.world.geometry", "RegionError"),
    ("ringtrack.tools.console", "UsageError"),
    ("ringtrack.tools.console", "OutputError"),
    ("ringtrack.bus.config", "BusError"),
    ("ringtrack.bus.identity", "IdCollision"),
    ("ringtrack.tools.runlog", "LogError"),
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


def build_parser(commands: Sequence[str] = tuple(COMMANDS)) -> argparse.ArgumentParser:
    parser = Parser(
        prog="ringtrack",
        description="Self-triggered multi-robot target tracking: engine, emulator over Zenoh, experiments.",
    )
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        importlib.import_module(f"ringtrack.tools.{name}").register(subcommands)
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
        from ringtrack.tools.console import err

        err.print(f"ringtrack: error: {error}", highlight=False, markup=False)
        return getattr(error, "exit_code", 2)
    except KeyboardInterrupt:
        print("ringtrack: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
