"""``ringtrack plot LOG -o PNG``: a run's trajectories, errors, polls and traffic in one figure."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.tools.cli.options import FIGURE_SUFFIXES, output_path
from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.runlog.plot import plot_run


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("plot", help="draw a run log: trajectories, Cerr/Terr, polls, traffic per link")
    parser.add_argument("log", type=Path, help="a run log (RUN_FOLDER/log.jsonl, or simulate --log)")
    parser.add_argument("-o", "--output", type=output_path(FIGURE_SUFFIXES), required=True, metavar="PNG",
                        help="figure to write (.png, .pdf or .svg)")
    parser.set_defaults(handler=run_plot)


def run_plot(args: argparse.Namespace) -> int:
    log = read_log(args.log)
    if not log.steps:
        raise UsageError(f"{args.log}: the log has no steps to draw")
    plot_run(log).savefig(args.output, dpi=110)
    out.print(f"wrote {args.output}", highlight=False)
    return 0
