"""``ringtrack replay LOG``: watch any run again, from its log, on the live dashboard."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console

from ringtrack.tools.cli.options import positive
from ringtrack.tools.dashboard.dashboard import Dashboard
from ringtrack.tools.dashboard.replay import ending, replay
from ringtrack.tools.dashboard.views import LiveView
from ringtrack.tools.monitor.state import TeamModel
from ringtrack.tools.output.console import out
from ringtrack.tools.runlog.log import read_log


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("replay", help="watch a run again from its log on the dashboard")
    parser.add_argument("log", type=Path, help="a run log (RUN_FOLDER/log.jsonl, or simulate --log)")
    parser.add_argument("--speed", type=positive, default=10.0,
                        help="simulated seconds per wall second (default 10; 1e9 shows the end at once)")
    display = parser.add_mutually_exclusive_group()
    display.add_argument("--dashboard", action="store_true", help="draw the dashboard even without a terminal")
    display.add_argument("--no-dashboard", action="store_true", help="plain summary lines instead")
    display.add_argument("--final", action="store_true",
                         help="print only the dashboard of the last step, once, as text (for reports)")
    parser.set_defaults(handler=run_replay)


def run_replay(args: argparse.Namespace) -> int:
    log = read_log(args.log)
    model = TeamModel(log.scenario, log.header["clock"], replay_speed=args.speed, live=False)
    model.steps = log.header["steps"]
    if args.final:
        for record in log.records:
            model.add(record)
        model.status = ending(log)
        if log.end:
            model.add(log.end)
        model.replay_speed = None
        out.print(Dashboard(model))
        return 0
    console = Console(force_terminal=True) if args.dashboard else out
    dashboard = args.dashboard or (console.is_terminal and not args.no_dashboard)
    with LiveView(console, model, dashboard) as view:
        replay(model, log.records, args.speed, view.refresh)
        model.status = ending(log)
        if log.end:
            model.add(log.end)
        view.refresh(True)
    return 0
