"""``ringtrack list``, ``echo`` and ``hz``: look at a live run from outside, as ``ros2 node list``,
``ros2 topic echo`` and ``ros2 topic hz`` do, through a passive :class:`bus.observer.Observer`.

Attaching or detaching one never changes a run: the observer publishes nothing and declares no
liveliness token (the world's wait for its monitor and the rosters never see it), and it drops
samples itself rather than hold a sender up. ``RUN`` is a spawn run folder (its ``run.json`` gives
the run id and the world's endpoints) or a run id in hex with ``--connect`` (a router or any peer
of the run), or found under ``--runs``.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
from rich.table import Table

from ringtrack.bus.config import LOOPBACK_ANY_PORT, BusConfig
from ringtrack.bus.keys import robot_name
from ringtrack.bus.messages import KINDS, AnyMessage, End, Rejected, peek
from ringtrack.bus.observer import Heard, Observer, Token
from ringtrack.tools.console import UsageError, err, out
from ringtrack.tools.options import at_least, positive

POLL_S = 0.05
QUIET_S = 3.0  # echo and hz give up on a run heard nothing of for this long (default of --give-up)
HEX_RUN = re.compile(r"^[0-9a-fA-F]{1,8}$")


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


@dataclass
class Target:
    """What to watch: a run id (None: every run) and the endpoints to reach it through; the run
    folder's expected participants when there is one."""

    run: int | None
    connect: list[str]
    folder: Path | None = None
    expected: list[str] = field(default_factory=list)


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


def expected_names(folder: Path) -> list[str]:
    """The participants a spawn run folder's scenario starts with (world, fusion, monitor, robots)."""
    from ringtrack.world.scenario import load_scenario

    scenario = load_scenario(str(folder / "scenario.toml"))
    fusion = ["fusion"] if scenario.estimation.mode == "centralized" else []
    return ["world", *fusion, "monitor", *(robot_name(robot) for robot in range(scenario.robots))]


def observer(target: Target, mode: str) -> Observer:
    config = BusConfig(mode=mode, listen=(LOOPBACK_ANY_PORT,), connect=tuple(target.connect))  # type: ignore[arg-type]
    return Observer(config, target.run)


# ---------------------------------------------------------------------------- list
@dataclass
class Seen:
    """One participant of a run as heard: its token, and the kinds and destinations it published."""

    alive: bool | None = None  # None: no token seen either way
    published: dict[str, set[str]] = field(default_factory=lambda: defaultdict(set))  # kind -> destinations
    messages: int = 0


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
        out.print(list_table(run, participants, args.duration))
    return 0


def list_table(run: int, participants: dict[str, Seen], duration: float) -> Table:
    """One row per participant: alive (token held), gone (withdrawn, or expected and absent) or heard
    only (published without a token), its messages per second and the key expressions it published."""
    alive = sum(1 for seen in participants.values() if seen.alive)
    table = Table(title=f"run {run:08x}: {len(participants)} participants, {alive} alive", title_justify="left",
                  caption="keys: ringtrack/<run>/<destination>/<source>/<kind>; {a,b} several destinations",
                  caption_justify="left")
    for column, justify in (("participant", "left"), ("state", "left"), ("msg/s", "right"), ("publishes", "left")):
        table.add_column(column, justify=justify, overflow="fold")  # type: ignore[arg-type]
    order = {"world": -3, "fusion": -2, "monitor": -1}
    for name in sorted(participants, key=lambda name: (order.get(name, 0), len(name), name)):
        seen = participants[name]
        state = "alive" if seen.alive else "gone" if seen.alive is False else "heard only"
        keys = [f"ringtrack/{run:08x}/{_braced(sorted(destinations))}/{name}/{kind}"
                for kind, destinations in sorted(seen.published.items())]
        table.add_row(name, state, f"{seen.messages / duration:.0f}", "\n".join(keys) or "-",
                      style=None if seen.alive else "red" if seen.alive is False else "yellow")
    return table


def _braced(names: list[str]) -> str:
    return names[0] if len(names) == 1 else "{" + ",".join(names) + "}"


class Quiet:
    """Ends a watch of one run: nothing of it heard for ``give_up_s`` seconds (not running, or
    unreachable), or its world withdrew its token (the run is over)."""

    def __init__(self, run: int | None, give_up_s: float = QUIET_S) -> None:
        self.run = run
        self.give_up_s = give_up_s
        self.last = time.monotonic()
        self.reason = ""
        self.run_ended = False  # the world withdrew its token: a normal end of the watch

    def heard(self, item: Heard | Token) -> None:
        self.last = item.at
        if isinstance(item, Token) and item.name == "world" and not item.up:
            self.reason, self.run_ended = "the world left: the run is over", True

    def over(self) -> bool:
        if not self.reason and time.monotonic() - self.last > self.give_up_s:
            self.reason = (f"nothing of run {self.run:08x} heard for {self.give_up_s:g} s: is it running? "
                           "(ringtrack list)")
        return bool(self.reason)


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


def echo_line(heard: Heard, message: AnyMessage | None) -> str:
    """``kind source>destination size B step k: field=value ...`` (floats to 4 significant digits,
    fields that are None left out)."""
    route = heard.route
    head = f"{route.kind:<11} {route.source + '>' + route.destination:<13} {len(heard.payload):>4} B"
    if message is None:
        return f"{head} (not a message: dropped by every participant)"
    fields = {name: value for name, value in msgspec.structs.asdict(message).items()
              if name not in ("schema", "run") and value is not None}
    step = fields.pop("step", None)
    text = " ".join(f"{name}={_short(value)}" for name, value in fields.items())
    return f"{head}" + (f" step {step}:" if step is not None else ":") + f" {text}"


def _short(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        inner = ",".join(_short(item) for item in value)
        return f"({inner})" if isinstance(value, tuple) else f"[{inner}]"
    if isinstance(value, dict):
        return "{" + ",".join(f"{key}:{_short(item)}" for key, item in value.items()) + "}"
    return str(value)


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
                    out.print(hz_table(messages, sizes, time.monotonic() - started), highlight=False)
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
                out.print(hz_table(messages, sizes, elapsed), highlight=False)
                reports += 1
                if args.reports and reports >= args.reports:
                    return 0
                messages, sizes, started = Counter(), Counter(), time.monotonic()
            time.sleep(POLL_S)
    return 0


def hz_table(messages: Counter[tuple[str, str]], sizes: Counter[tuple[str, str]], seconds: float) -> Table:
    """Messages and payload bytes per second over ``seconds``, per kind then per link."""
    table = Table(title=f"over {seconds:.2f} s", title_justify="left", show_edge=False, pad_edge=False)
    for column in ("kind / link", "msg/s", "B/s", "B/msg"):
        table.add_column(column, justify="right")
    for what in ("kind", "link"):
        keys = sorted((key for key in messages if key[0] == what), key=lambda key: -messages[key])
        for index, key in enumerate(keys):
            count, size = messages[key], sizes[key]
            table.add_row(key[1], f"{count / seconds:.1f}", f"{size / seconds:.0f}",
                          f"{size / count:.1f}" if count else "-", end_section=index == len(keys) - 1)
    if not messages:
        table.add_row("(nothing heard)", "0", "0", "-")
    return table
