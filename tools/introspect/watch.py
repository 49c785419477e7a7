"""``ringtrack list``, ``echo`` and ``hz``: look at a live run from outside, as ``ros2 node list``,
``ros2 topic echo`` and ``ros2 topic hz`` do, through a passive :class:`bus.observer.Observer`.

Attaching or detaching one never changes a run: the observer publishes nothing and declares no
liveliness token (the world's wait for its monitor and the rosters never see it), and it drops
samples itself rather than hold a sender up. ``RUN`` is a spawn run folder (its ``run.json`` gives
the run id and the world's endpoints) or a run id in hex with ``--connect`` (a router or any peer
of the run), or found under ``--runs``.
"""

from __future__ import annotations

import json
import re
import time
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
from rich.table import Table

from ringtrack.bus.config import LOOPBACK_ANY_PORT, BusConfig
from ringtrack.bus.messages import AnyMessage, Rejected, peek
from ringtrack.bus.observer import Heard, Observer, Token
from ringtrack.tools.monitor.state import startup_names
from ringtrack.tools.output.console import UsageError
from ringtrack.world.scenario import load_scenario

POLL_S = 0.05
QUIET_S = 3.0  # echo and hz give up on a run heard nothing of for this long (default of --give-up)
HEX_RUN = re.compile(r"^[0-9a-fA-F]{1,8}$")


@dataclass
class Target:
    """What to watch: a run id (None: every run) and the endpoints to reach it through; the run
    folder's expected participants when there is one."""

    run: int | None
    connect: list[str]
    folder: Path | None = None
    expected: list[str] = field(default_factory=list)


def find_run(run: str | None, connect: list[str] | None, runs: Path) -> Target:
    """The run to watch and the endpoints to reach it through: ``run`` a spawn run folder (holding
    ``run.json``) or a run id in hex (found under ``runs`` unless ``connect`` names endpoints), or
    None for every run heard; ``connect`` else the endpoints of the run folders under ``runs``."""
    folder: Path | None = None
    if run is not None and (Path(run) / "run.json").is_file():
        folder = Path(run)
    elif run is not None and HEX_RUN.match(run):
        matches = sorted(runs.glob(f"*-{int(run, 16):08x}/run.json"))
        folder = matches[-1].parent if matches and not connect else None
    elif run is not None:
        raise UsageError(f"RUN {run!r}: give a run folder (holding run.json) or a run id in hex like 1f2e3d4c")
    if folder is not None:
        info = json.loads((folder / "run.json").read_text())
        return Target(int(info["run"], 16), list(connect or info["connect"]), folder, expected_names(folder))
    endpoints = list(connect or [])
    if not endpoints:
        for run_file in sorted(runs.glob("*/run.json")):
            endpoints += [endpoint for endpoint in json.loads(run_file.read_text())["connect"]
                          if endpoint not in endpoints]
    if not endpoints:
        raise UsageError("no endpoint to reach the bus: give --connect ENDPOINT (a router or a peer of the run) "
                         "or a run folder")
    return Target(None if run is None else int(run, 16), endpoints)


def expected_names(folder: Path) -> list[str]:
    """The participants a spawn run folder's scenario starts with (world, fusion, monitor, robots)."""
    return startup_names(load_scenario(str(folder / "scenario.toml")))


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


def listen(target: Target, mode: str, duration_s: float) -> dict[int, dict[str, Seen]]:
    """Every run heard on the bus in ``duration_s`` seconds (or the target run, heard or not), with
    its participants as heard; the target's expected participants that were not heard are gone."""
    runs: dict[int, dict[str, Seen]] = defaultdict(dict)
    with observer(target, mode) as bus:
        deadline = time.monotonic() + duration_s
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
        participants = runs[target.run]
        for name in target.expected:
            participants.setdefault(name, Seen(alive=False))
    return dict(runs)


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


def messages(target: Target, mode: str, quiet: Quiet, kinds: set[str],
             robot: str | None = None) -> Iterator[tuple[Heard, AnyMessage | None]]:
    """The target run's messages of ``kinds`` (from or to ``robot``, if named) as they pass, each
    with its decoded message (None: not a message, every participant drops it), until ``quiet``
    says the watch is over."""
    with observer(target, mode) as bus:
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
                yield item, message
            time.sleep(POLL_S)


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


@dataclass
class Window:
    """What passed in ``seconds`` of a watch: messages and payload bytes per ``("kind", kind)`` and
    per ``("link", "source>destination")``."""

    seconds: float
    messages: Counter[tuple[str, str]] = field(default_factory=Counter)
    sizes: Counter[tuple[str, str]] = field(default_factory=Counter)


def rates(target: Target, mode: str, quiet: Quiet, period_s: float) -> Iterator[Window]:
    """Every ``period_s`` seconds what the target run sent in that time, until its world's End (the
    last window up to it) or until ``quiet`` says the watch is over (with what was counted since
    the last window when the run ended)."""
    with observer(target, mode) as bus:
        window, started, ended = Window(0.0), time.monotonic(), False
        while not ended:
            if quiet.over():
                if quiet.run_ended and window.messages:
                    window.seconds = time.monotonic() - started
                    yield window
                return
            for item in bus.poll():
                quiet.heard(item)
                if isinstance(item, Heard):
                    for key in (("kind", item.route.kind), ("link", f"{item.route.source}>{item.route.destination}")):
                        window.messages[key] += 1
                        window.sizes[key] += len(item.payload)
                    ended = ended or item.route.kind == "end"
            elapsed = time.monotonic() - started
            if elapsed >= period_s or ended:
                window.seconds = elapsed
                yield window
                window, started = Window(0.0), time.monotonic()
            time.sleep(POLL_S)


def hz_table(window: Window) -> Table:
    """Messages and payload bytes per second over the window, per kind then per link."""
    messages, sizes, seconds = window.messages, window.sizes, window.seconds
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
