"""``ringtrack monitor``: tally a team's messages live, draw the dashboard and write the run log."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import time
from pathlib import Path
from typing import NoReturn

from rich.console import Console

from ringtrack.agents.summary import RunSummary, summarise
from ringtrack.bus.config import announced_endpoints
from ringtrack.bus.keys import MONITOR
from ringtrack.tools.cli.options import LOG_FILE, MCAP_FILE, foxglove_address, scenario_from_arguments
from ringtrack.tools.cli.role_flags import bus_config, common_flags, digests, finished
from ringtrack.tools.dashboard.startup import started_at
from ringtrack.tools.dashboard.views import LiveView, print_outcome, print_report
from ringtrack.tools.monitor.monitor import run_monitor
from ringtrack.tools.monitor.state import TeamModel, startup_names
from ringtrack.tools.output.console import UsageError, err, out
from ringtrack.tools.runlog.log import LogError, LogWriteError, history_from_log, read_log
from ringtrack.tools.viz.extra import VIZ_EXTRA, require_sdk
from ringtrack.tools.viz.sink import LiveServer, write_mcap
from ringtrack.world.scenario import Scenario


def register(commands: argparse._SubParsersAction) -> None:
    monitor = commands.add_parser("monitor", help="tally a team's messages live and write its run log")
    common_flags(monitor)
    monitor.add_argument("--log", type=LOG_FILE, required=True, metavar="PATH", help="run log to write (JSON lines)")
    monitor.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                         help="the world's clock, shown on the dashboard and written to the log (default lockstep)")
    display = monitor.add_mutually_exclusive_group()
    display.add_argument("--dashboard", action="store_true", help="draw the live dashboard even without a terminal")
    display.add_argument("--no-dashboard", action="store_true", help="plain summary lines instead of the dashboard")
    monitor.add_argument("--connect-from", type=Path, metavar="PATH",
                         help="wait for PATH (written by world --announce) and connect to the endpoints it lists; "
                         "the dashboard shows the start-up meanwhile")
    monitor.add_argument("--display-handover", type=Path, metavar="PATH",
                         help="spawn draws the start-up frame and wrote PATH: count from its time, write 'ready' "
                         "there when ready to draw, and draw once spawn has removed PATH (or after 30 s)")
    monitor.add_argument("--resume", action="store_true",
                         help="go on with the run log (and books) of a monitor of the same run that went away, after "
                         "its last complete step; the world must hold the run for it (world --monitor-grace)")
    monitor.add_argument("--all-robots", action="store_true",
                         help="list every robot and link in the end-of-run report (default: above 20, "
                         "min/median/max and the 5 busiest)")
    add_foxglove_arguments(monitor)
    monitor.set_defaults(handler=run_monitor_role)


def add_foxglove_arguments(parser: argparse.ArgumentParser) -> None:
    """``--foxglove [HOST:]PORT`` and ``--record FILE.mcap`` (the monitor's, and spawn's for it)."""
    parser.add_argument("--foxglove", type=foxglove_address, metavar="[HOST:]PORT",
                        help="serve the run live to Foxglove over its WebSocket protocol (ws://HOST:PORT; HOST "
                        f"defaults to 127.0.0.1, this machine only; PORT 0: a free one) ({VIZ_EXTRA})")
    parser.add_argument("--record", type=MCAP_FILE, metavar="FILE.mcap",
                        help=f"write the run as MCAP as it ends, what export --mcap writes from its log ({VIZ_EXTRA})")


def check_foxglove_arguments(args: argparse.Namespace) -> None:
    """Without the viz extra, ``--foxglove`` and ``--record`` are one line naming it (exit code 2)."""
    for flag in ("foxglove", "record"):
        if getattr(args, flag) is not None:
            require_sdk(f"--{flag}")


def live_server(args: argparse.Namespace, scenario: Scenario) -> LiveServer | None:
    """The live view ``--foxglove`` asks for (None: none); says where it listens."""
    if args.foxglove is None:
        return None
    view = LiveServer(scenario, serve=args.foxglove)
    err.print(f"monitor: Foxglove live view on ws://{args.foxglove[0]}:{view.port}", highlight=False)
    return view


def run_monitor_role(args: argparse.Namespace) -> int:
    check_foxglove_arguments(args)
    scenario = scenario_from_arguments(args)
    viewer = live_server(args, scenario)
    model = TeamModel(scenario, args.clock)
    model.expected, model.up = startup_names(scenario), {MONITOR}
    if args.display_handover is not None:
        model.started = started_at(args.display_handover) or model.started  # spawn's frame counted from then
    console = Console(force_terminal=True) if args.dashboard else out
    dashboard = args.dashboard or (console.is_terminal and not args.no_dashboard)
    try:
        with LiveView(console, model, dashboard, handover=args.display_handover) as view:
            if args.connect_from is not None:
                args.connect = [*(args.connect or []), *wait_for_endpoints(args.connect_from)]
            code, report = asyncio.run(
                run_monitor(scenario, scenario.seed, args.run, bus_config(args, [MONITOR], scenario.robots),
                            args.log, scenario.max_steps, args.clock, model, view.refresh, args.exit_with_parent,
                            digests(args), viewer, resume=args.resume)
            )
    except LogWriteError as error:
        log_write_failed(error)
    finally:
        if viewer is not None:
            viewer.close()
    if args.record is not None and args.log.exists():  # from the log, as export --mcap: no step pays for it
        try:
            write_mcap(read_log(args.log), args.record)
        except (LogError, OSError) as error:
            err.print(f"monitor: --record {args.record}: not written ({error}); the run log stays", highlight=False)
            code = code or 1
    if report is not None:
        # The log is complete: a second signal (the supervisor's, halfway through its grace) must not
        # cut the report short.
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, signal.SIG_IGN)
        print_report(out, report, all_robots=args.all_robots)
        outcome = run_outcome(args.log)
        if outcome is not None:
            print_outcome(out, outcome, report)
        if not report.consistent():
            err.print("monitor: warning: the traffic seen differs from what the senders counted (lost or injected "
                      "messages; see the table and the log's end record)", highlight=False)
    return finished("monitor", code)


ENDPOINTS_TIMEOUT_S = 20.0


def wait_for_endpoints(path: Path, timeout_s: float = ENDPOINTS_TIMEOUT_S) -> list[str]:
    """The endpoints announced in ``path`` (``world --announce``), waiting at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while (endpoints := announced_endpoints(path)) is None:
        if time.monotonic() > deadline:
            raise UsageError(f"--connect-from {path}: no endpoints announced within {timeout_s:.0f} s; start the "
                             "world with --announce PATH")
        time.sleep(0.02)
    return endpoints


def run_outcome(log_path: Path) -> RunSummary | None:
    """The summary (Ctime, Com-bar, ...) of the run a log holds, None when it has no step."""
    log = read_log(log_path)
    return summarise(history_from_log(log)) if log.steps else None


def log_write_failed(error: Exception) -> NoReturn:
    """End a monitor whose run log could not be written with ``LogWriteError.exit_code``, whatever
    becomes of its message: its standard error may be a file on the same full disk, and a failed
    flush at interpreter exit would turn the code into 120."""
    with contextlib.suppress(OSError):
        err.print(f"monitor: {error}; stopping", highlight=False, markup=False)
    os._exit(LogWriteError.exit_code)
