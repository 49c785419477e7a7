"""``ringtrack list``, ``echo`` and ``hz``: a live run looked at from outside, on its bus."""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter, defaultdict
from pathlib import Path

from ringtrack.bus.keys import robot_name
from ringtrack.bus.messages import KINDS, AnyMessage, End, Rejected, peek
from ringtrack.bus.observer import Heard, Token
from ringtrack.tools.cli.options import at_least, positive
from ringtrack.tools.introspect.watch import (
    HEX_RUN,
    POLL_S,
    QUIET_S,
    Quiet,
    Seen,
    Target,
    echo_line,
    expected_names,
    hz_table,
    list_table,
    observer,
)
from ringtrack.tools.output.console import UsageError, err, out, show


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


def resolve(args: argparse.Namespace) -> Target:
    """The run and endpoints the flags name (see the module docstring)."""
    text: str | None = args.run
    folder: Path | None = None
    if text is not None and (Path(text) / "run.json").is_file():
        folder = Path(text)
    elif text is not None and HEX_RUN.match(text):
        matches = sorted(args.runs.glob(f"*-{int(text, 16):08x}/run.json"))
        folder = matches[-1].parent if matches and not args.connect else None
    elif text is not None:
        raise UsageError(f"RUN {text!r}: give a run folder (holding run.json) or a run id in hex like 1f2e3d4c")
    if folder is not None:
        info = json.loads((folder / "run.json").read_text())
        return Target(int(info["run"], 16), list(args.connect or info["connect"]), folder, expected_names(folder))
    run = int(text, 16) if text is not None else None
    connect = list(args.connect or [])
    if not connect:
        for run_file in sorted(args.runs.glob("*/run.json")):
            connect += [endpoint for endpoint in json.loads(run_file.read_text())["connect"] if endpoint not in connect]
    if not connect:
        raise UsageError("no endpoint to reach the bus: give --connect ENDPOINT (a router or a peer of the run) "
                         "or a run folder")
    return Target(run, connect)


def run_list(args: argparse.Namespace) -> int:
    target = resolve(args)
    runs: dict[int, dict[str, Seen]] = defaultdict(dict)
    with observer(target, args.mode) as bus:
        deadline = time.monotonic() + args.duration
        while time.monotonic() < deadline:
            for item in bus.poll():
                if isinstance(item, Token):
                    runs[item.run].setdefault(item.name, Seen()).alive = item.up
                else:
                    seen = runs[item.run].setdefault(item.route.source, Seen())
                    seen.published[item.route.kind].add(item.route.destination)
                    seen.messages += 1
            time.sleep(POLL_S)
    if target.run is not None:
        runs.setdefault(target.run, {})
    if not runs:
        out.print(f"no run heard in {args.duration:g} s through {', '.join(target.connect)}", highlight=False)
        return 1
    for run, participants in sorted(runs.items()):
        for name in target.expected if run == target.run else []:
            participants.setdefault(name, Seen(alive=False))
        show(list_table(run, participants, args.duration))
    return 0


# ---------------------------------------------------------------------------- echo
def run_echo(args: argparse.Namespace) -> int:
    target = resolve(args)
    kinds = set(args.kind or KINDS)
    robot = None if args.robot is None else robot_name(args.robot)
    printed = 0
    quiet = Quiet(target.run, args.give_up_s)
    with observer(target, args.mode) as bus:
        while not quiet.over():
            for item in bus.poll():
                quiet.heard(item)
                if not isinstance(item, Heard) or item.route.kind not in kinds:
                    continue
                if robot is not None and robot not in (item.route.source, item.route.destination):
                    continue
                try:
                    message: AnyMessage | None = peek(item.payload)
                except Rejected:
                    message = None
                out.print(echo_line(item, message), highlight=False, soft_wrap=True, markup=False)
                printed += 1
                if (args.count and printed >= args.count) or isinstance(message, End):
                    return 0
            time.sleep(POLL_S)
    err.print(f"echo: {quiet.reason}", highlight=False)
    return 0 if quiet.run_ended else 1


# ---------------------------------------------------------------------------- hz
def run_hz(args: argparse.Namespace) -> int:
    target = resolve(args)
    reports = 0
    with observer(target, args.mode) as bus:
        started = time.monotonic()
        messages: Counter[tuple[str, str]] = Counter()  # (what, name) -> messages
        sizes: Counter[tuple[str, str]] = Counter()
        ended = False
        quiet = Quiet(target.run, args.give_up_s)
        while not ended:
            if quiet.over():
                if quiet.run_ended and messages:  # what was counted since the last report
                    show(hz_table(messages, sizes, time.monotonic() - started))
                err.print(f"hz: {quiet.reason}", highlight=False)
                return 0 if quiet.run_ended else 1
            for item in bus.poll():
                quiet.heard(item)
                if isinstance(item, Heard):
                    for key in (("kind", item.route.kind), ("link", f"{item.route.source}>{item.route.destination}")):
                        messages[key] += 1
                        sizes[key] += len(item.payload)
                    ended = ended or item.route.kind == "end"
            elapsed = time.monotonic() - started
            if elapsed >= args.period or ended:
                show(hz_table(messages, sizes, elapsed))
                reports += 1
                if args.reports and reports >= args.reports:
                    return 0
                messages, sizes, started = Counter(), Counter(), time.monotonic()
            time.sleep(POLL_S)
    return 0
