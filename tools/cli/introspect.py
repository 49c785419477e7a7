"""``ringtrack list``, ``echo`` and ``hz``: a live run looked at from outside, on its bus."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.bus.keys import robot_name
from ringtrack.bus.messages import KINDS, End
from ringtrack.tools.cli.options import at_least, positive
from ringtrack.tools.introspect.watch import (
    QUIET_S,
    Quiet,
    echo_line,
    find_run,
    hz_table,
    list_table,
    listen,
    messages,
    rates,
)
from ringtrack.tools.output.console import err, out, show


def register(commands: argparse._SubParsersAction) -> None:
    listing = commands.add_parser("list", help="runs on the bus: participants, alive or gone, key expressions",
                                  description="Listen for --duration seconds and list every run heard (or RUN): "
                                  "its participants, whether each holds its liveliness token, what it publishes.")
    _common(listing, run_required=False)
    listing.add_argument("--duration", type=positive, default=1.0, metavar="S",
                         help="seconds to listen before listing (default 1)")
    listing.set_defaults(handler=run_list)

    echo = commands.add_parser("echo", help="print a live run's messages, one decoded line each",
                               description="Print every message of RUN as it passes, decoded, one line each "
                               "(like ros2 topic echo); stops after --count messages or when the run ends.")
    _common(echo, run_required=True)
    echo.add_argument("--kind", action="append", choices=sorted(KINDS), metavar="K",
                      help=f"only messages of this kind ({', '.join(sorted(KINDS))}); repeatable")
    echo.add_argument("--robot", type=at_least(0), metavar="I", help="only messages from or to robot I")
    echo.add_argument("--count", type=at_least(1), metavar="N", help="stop after N messages")
    _give_up(echo)
    echo.set_defaults(handler=run_echo)

    hz = commands.add_parser("hz", help="messages and bytes per second of a live run, per kind and per link",
                             description="Every --period seconds, the messages and payload bytes per second of "
                             "RUN by kind and by link (like ros2 topic hz); stops after --reports reports or "
                             "when the run ends.")
    _common(hz, run_required=True)
    hz.add_argument("--period", type=positive, default=1.0, metavar="S", help="seconds per report (default 1)")
    hz.add_argument("--reports", type=at_least(1), metavar="N", help="stop after N reports")
    _give_up(hz)
    hz.set_defaults(handler=run_hz)


def _give_up(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--give-up", type=positive, default=QUIET_S, metavar="S", dest="give_up_s",
                        help=f"stop when nothing of RUN is heard for S seconds (default {QUIET_S:g})")


def _common(parser: argparse.ArgumentParser, run_required: bool) -> None:
    parser.add_argument("run", nargs=None if run_required else "?", metavar="RUN",
                        help="a spawn run folder, or a run id in hex" + ("" if run_required else
                                                                       " (default: every run heard)"))
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="a router or peer of the run, e.g. tcp/127.0.0.1:7447; repeatable (default: the "
                        "world's endpoints from the run folder, or those of every run folder under --runs)")
    parser.add_argument("--mode", choices=["peer", "client"], default="peer",
                        help="Zenoh mode: peer (default; gossip links it to every peer of the run) or client "
                        "(of a router)")
    parser.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR",
                        help="where to look for run folders (default runs)")


def run_list(args: argparse.Namespace) -> int:
    target = find_run(args.run, args.connect, args.runs)
    runs = listen(target, args.mode, args.duration)
    if not runs:
        out.print(f"no run heard in {args.duration:g} s through {', '.join(target.connect)}", highlight=False)
        return 1
    for run, participants in sorted(runs.items()):
        show(list_table(run, participants, args.duration))
    return 0


def run_echo(args: argparse.Namespace) -> int:
    target = find_run(args.run, args.connect, args.runs)
    quiet = Quiet(target.run, args.give_up_s)
    robot = None if args.robot is None else robot_name(args.robot)
    for printed, (heard, message) in enumerate(messages(target, args.mode, quiet, set(args.kind or KINDS), robot),
                                               start=1):
        out.print(echo_line(heard, message), highlight=False, soft_wrap=True, markup=False)
        if (args.count and printed >= args.count) or isinstance(message, End):
            return 0
    err.print(f"echo: {quiet.reason}", highlight=False)
    return 0 if quiet.run_ended else 1


def run_hz(args: argparse.Namespace) -> int:
    target = find_run(args.run, args.connect, args.runs)
    quiet = Quiet(target.run, args.give_up_s)
    for reports, window in enumerate(rates(target, args.mode, quiet, args.period), start=1):
        show(hz_table(window))
        if args.reports and reports >= args.reports:
            return 0
    if quiet.reason:
        err.print(f"hz: {quiet.reason}", highlight=False)
    return 0 if quiet.run_ended or not quiet.reason else 1
