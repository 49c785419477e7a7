"""``ringtrack strategies``: every registered strategy (and any strategy file given), what it does
and the parameters a scenario's ``[strategy]`` section sets for it (:func:`agents.strategy.describe_strategies`)."""

from __future__ import annotations

import argparse
import json

from rich.table import Table
from rich.text import Text

from ringtrack.agents.strategy import StrategyDescription, StrategyError, describe_strategies
from ringtrack.tools.output.console import UsageError, out, show


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "strategies",
        help="list the communication strategies and their parameters",
        description="List every registered strategy (and those the given files define): its label, what it does "
        "and the parameters a scenario sets in its [strategy] section (name, type, default, units, help).",
    )
    parser.add_argument("files", nargs="*", metavar="FILE.py", help="also describe the strategy these files define")
    parser.add_argument("--json", action="store_true", help="print the descriptions as JSON instead of tables")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    try:
        described = describe_strategies(tuple(args.files))
    except StrategyError as error:
        raise UsageError(str(error)) from None
    if args.json:
        out.print_json(json.dumps([description.to_json() for description in described]))
        return 0
    for description in described:
        out.print(strategy_heading(description))
        if description.parameters:
            show(parameter_table(description))
        else:
            out.print("  no parameters", style="dim")
        out.print()
    return 0


def strategy_heading(description: StrategyDescription) -> Text:
    """``name (label): what it does``, and what it needs or reports when that is not the default."""
    heading = Text(description.name, style="bold")
    if description.label != description.name:
        heading.append(f" ({description.label})")
    heading.append(f": {description.description}")
    notes = ([f"needs estimation.mode = '{description.estimation}'"] if description.estimation else []) + \
        (["Cerr from true positions"] if description.cerr == "true" else [])
    if notes:
        heading.append(f" [{'; '.join(notes)}]", style="dim")
    return heading


HELP_WIDTH = 60  # columns of a parameter's help text: prose wraps


def parameter_table(description: StrategyDescription) -> Table:
    """The strategy's parameters: key, type, default, units, what values it takes and what it does."""
    table = Table(box=None, padding=(0, 1, 0, 2), show_edge=False)
    for column in ("parameter", "type", "default", "units", "values", "help"):
        table.add_column(column, overflow="fold", max_width=HELP_WIDTH if column == "help" else None)
    for parameter in description.parameters:
        table.add_row(parameter.name, parameter.type.__name__, json.dumps(parameter.default), parameter.units or "-",
                      parameter.expects, parameter.help)
    return table
