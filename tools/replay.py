"""``ringtrack replay LOG``: watch any run again, from its log, on the live dashboard."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from rich.console import Console

from ringtrack.tools.console import out
from ringtrack.tools.dashboard import Dashboard, TeamModel, ending_text
from ringtrack.tools.options import positive
from ringtrack.tools.runlog import RunLog, read_log
from ringtrack.tools.views import LiveView

FRAME_S = 0.1  # at most ten redraws per wall second


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


def ending(log: RunLog) -> str:
    """The status the last frame shows: why the run ended, or that its log stops short."""
    return ending_text(log.end["reason"]) if log.end else "log ends here (the run was stopped)"


def replay(model: TeamModel, records: list[dict], speed: float, refresh: Callable[[bool], None]) -> None:
    """Feed ``records`` (steps and events, in file order) to ``model``, each step at its simulated
    time over ``speed`` (simulated seconds per wall second), redrawing at most every ``FRAME_S``."""
    first = next((record["time"] for record in records if record["type"] == "step"), None)
    if first is None:
        return
    started = time.monotonic()
    last_frame = 0.0
    for record in records:
        if record["type"] == "step":
            wait = (record["time"] - first) / speed - (time.monotonic() - started)
            if wait > 0:
                time.sleep(wait)
        model.add(record)
        now = time.monotonic()
        if now - last_frame >= FRAME_S:
            refresh(False)
            last_frame = now
