"""The live dashboard: what a team is doing and what every message cost.

:class:`TeamModel` is built from run-log step and event records, fed live by the monitor as it
writes them or read back from a log by ``ringtrack replay`` in file order, so both show exactly the
same thing. :class:`Dashboard` renders a model with rich: the region drawn in the terminal with the
robots, the true target and the estimates; a row per robot, with the state of its links to its ring
neighbours; traffic totals and rates, the messages saved against the constant strategy; Cerr and
Terr sparklines. It adapts to the console size at every render.
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from rich import box
from rich.console import Console, ConsoleOptions, Group, RenderResult
from rich.table import Table
from rich.text import Text

from ringtrack.agents.laws import Trigger
from ringtrack.tools.runlog import LINK_EVENTS
from ringtrack.world.geometry import angle_of
from ringtrack.world.metrics import convergence_error, true_offsets
from ringtrack.world.scenario import Scenario

HISTORY = 600  # steps of Cerr/Terr kept for the sparklines
SPARKS = "▁▂▃▄▅▆▇█"
ROBOT_ROWS = 24  # robots listed; the caption counts the others
CATEGORIES = ("robot", "world", "estimation")

REASONS = {  # short codes, explained in the robot table's caption
    Trigger.START: "start",
    Trigger.SCHEDULE: "every",
    Trigger.UNCERTAINTY: "T1",
    Trigger.SUCCESSOR: "T2",
    Trigger.PREDECESSOR: "T3",
    Trigger.UNKNOWN: "unk",
}
REASON_WIDTH = 19  # characters of the last-trigger column at most ("T1+T2+T3+unk @12345" fits)

LINK_MEMORY_STEPS = 10  # a fault stays on its link's cell for this many steps after the step it hit
FAULT_NAMES = {"duplicated": "dup", "delayed": "delay"}  # of link events; a drop is shown by its reason
LINK_STYLES = {"ok": "green", "dup": "yellow", "delay": "yellow"}  # any other state (a loss) is red


def reason_text(mask: int) -> str:
    """Short codes of the trigger conditions in a mask, joined by "+" ("-" for none)."""
    names = [name for flag, name in REASONS.items() if mask & flag]
    return "+".join(names) if names else "-"


def robot_label(robot: int) -> str:
    """One character per robot on the map: 0-9, then a-z, then A-Z, then '*'."""
    digits = "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
    return digits[robot] if robot < len(digits) else "*"


@dataclass
class RobotStatus:
    """One robot as of the latest step (angles in degrees about its own centre)."""

    angle: float = math.nan
    midpoint: float = math.nan
    ubd: float = math.nan
    ages: tuple[int, int] | None = None
    polls: int = 0
    polled_now: bool = False
    sent: list[int] = field(default_factory=lambda: [0, 0])  # messages, bytes (robot-to-robot)
    received: list[int] = field(default_factory=lambda: [0, 0])
    last_reason: int = 0
    last_reason_step: int = 0
    alive: bool = True


class TeamModel:
    """Everything the dashboard shows, updated one run-log record at a time."""

    def __init__(self, scenario: Scenario, clock: str, replay_speed: float | None = None, live: bool = True) -> None:
        self.scenario = scenario
        self.clock = clock
        self.replay_speed = replay_speed  # shown instead of the live rate when replaying
        self.live = live  # live: the rate shown is steps per wall second
        self.robots = [RobotStatus() for _ in range(scenario.robots)]
        self.step = 0
        self.time = 0.0
        self.steps = scenario.max_steps
        self.positions: np.ndarray | None = None
        self.target: np.ndarray | None = None
        self.centres: list | None = None
        self.totals = {category: [0, 0] for category in CATEGORIES}
        self.bytes_counted = True  # False for engine logs: nothing was sent, so no bytes were counted
        self.link_faults: dict[frozenset[int], tuple[str, int]] = {}  # ring link -> last fault, its step
        self.cerr: deque[float] = deque(maxlen=HISTORY)
        self.terr: deque[float] = deque(maxlen=HISTORY)
        self.started = time.monotonic()
        self.first_step_at: float | None = None
        self.status = "running"
        self.energy_j: dict[str, list[float]] = {}  # robot -> [transmit, receive] J, from the end record

    def add(self, record: dict) -> None:
        """Fold in one ``step``, ``event`` or ``end`` record of the run log (others change nothing)."""
        if record["type"] == "end":
            self.energy_j = dict(record.get("energy_j") or {})
        elif record["type"] == "step":
            self._add_step(record)
        elif record["type"] == "event" and record["event"] in LINK_EVENTS:
            name = record["reason"] if record["event"] == "dropped" else FAULT_NAMES[record["event"]]
            self.link_faults[frozenset((record["sender"], record["receiver"]))] = (name, record["step"])

    def _add_step(self, record: dict) -> None:
        if self.first_step_at is None:
            self.first_step_at = time.monotonic()
        self.step, self.time = record["step"], record["time"]
        self.positions = np.asarray(record["positions"], dtype=float)
        self.target = np.asarray(record["target"], dtype=float)
        self.centres = record["centre"]
        params = self.scenario.control
        live = set(record["live"])
        self.bytes_counted = record["sent_bytes"] is not None
        for index, status in enumerate(self.robots):
            status.alive = index in live
            trigger, centre = record["trigger"][index], record["centre"][index]
            status.polled_now = bool(trigger)
            if trigger:
                status.polls += 1
                status.last_reason, status.last_reason_step = trigger, self.step
            status.sent[0] += record["sent_messages"][index]
            status.received[0] += record["received_messages"][index]
            if self.bytes_counted:
                status.sent[1] += record["sent_bytes"][index]
                status.received[1] += record["received_bytes"][index]
            if centre is not None:
                theta = float(angle_of(self.positions[index], centre))
                status.angle = math.degrees(theta) % 360.0
                status.midpoint = math.degrees(theta + record["offset"][index]) % 360.0
            ages = record["ages"][index]
            if ages is not None:
                status.ages = (ages[0], ages[1])
                status.ubd = math.degrees(params.omega_max * (ages[0] + ages[1]) * params.dt / 4.0)
        for category, (messages, size) in record["traffic"].items():
            self.totals[category][0] += messages
            self.totals[category][1] += size or 0
        self.cerr.append(float(convergence_error(true_offsets(self.positions, self.target))))
        errors = [math.dist(centre, self.target) for centre in record["centre"] if centre is not None]
        self.terr.append(sum(errors) / len(errors) if errors else math.nan)

    def snapshot(self) -> TeamModel:
        """A copy to draw while this model goes on changing (the scenario, never changed, is shared)."""
        return copy.deepcopy(self, {id(self.scenario): self.scenario})

    # ------------------------------------------------------------------ derived figures
    def link_state(self, robot: int, neighbour: int) -> str:
        """The link between two ring neighbours: "gone" when ``neighbour`` is not live, else the last
        fault seen on it within ``LINK_MEMORY_STEPS`` steps (drop, outage, range, gone, radio, dup, delay),
        else "ok"."""
        if not self.robots[neighbour].alive:
            return "gone"
        fault = self.link_faults.get(frozenset((robot, neighbour)))
        if fault is not None and self.step - fault[1] < LINK_MEMORY_STEPS:
            return fault[0]
        return "ok"

    def size_text(self, size: int) -> str:
        """A byte count, or "-" when the log counted none (an engine run)."""
        return str(size) if self.bytes_counted else "-"

    @property
    def polls(self) -> int:
        return sum(status.polls for status in self.robots)

    def saved(self) -> tuple[int, float]:
        """Robot-to-robot messages saved against the constant strategy (every robot polls both
        neighbours every step: 4 messages per robot per step), and as a fraction of its total."""
        constant = 4 * len(self.robots) * self.step
        spent = self.totals["robot"][0]
        return constant - spent, (constant - spent) / constant if constant else 0.0

    def steps_per_second(self) -> float:
        """Steps per wall second since the first step (live), or 0 before it."""
        if self.first_step_at is None or self.step < 2:
            return 0.0
        elapsed = time.monotonic() - self.first_step_at
        return (self.step - 1) / elapsed if elapsed > 0 else 0.0

    def summary_line(self) -> str:
        """The plain one-line summary used without a terminal."""
        robot, world = self.totals["robot"], self.totals["world"]
        saved, share = self.saved()
        cerr = f"{self.cerr[-1]:.2f}" if self.cerr else "-"
        terr = f", Terr {self.terr[-1]:.3f} m" if self.terr and not math.isnan(self.terr[-1]) and \
            self.scenario.estimation.mode != "known" else ""
        return (f"step {self.step}/{self.steps}: robot-to-robot {robot[0]} msgs {self.size_text(robot[1])} B "
                f"(saved {saved} = {share:.0%} vs constant), world {world[0]} msgs, polls {self.polls}, "
                f"Cerr {cerr} deg{terr}")


# ---------------------------------------------------------------------------- rendering
def energy_text(energy_j: dict[str, list[float]]) -> Text:
    """The team's radio energy (known once the robots have reported it, at the end of a run)."""
    per_robot = [transmit + receive for transmit, receive in energy_j.values()]
    return Text.assemble(("radio energy: ", "bold"), f"team {1e3 * sum(per_robot):.2f} mJ, per robot "
                         f"{1e3 * min(per_robot):.2f}-{1e3 * max(per_robot):.2f} mJ")


def sparkline(values: list[float], width: int) -> Text:
    """``values`` (most recent last) as block characters, scaled between their min and max."""
    values = [value for value in values if not math.isnan(value)][-width:]
    if not values:
        return Text("-")
    low, high = min(values), max(values)
    span = high - low or 1.0
    return Text("".join(SPARKS[min(len(SPARKS) - 1, int((value - low) / span * len(SPARKS)))] for value in values))


def region_map(model: TeamModel, width: int, height: int) -> Text:
    """The region's boundary, the robots (their labels), the true target (x) and estimates (+)."""
    vertices = model.scenario.region.vertices
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    span = np.maximum(high - low, 1e-9)

    def cell(point: np.ndarray) -> tuple[int, int]:
        column = int(round((point[0] - low[0]) / span[0] * (width - 1)))
        row = int(round((high[1] - point[1]) / span[1] * (height - 1)))
        return min(max(row, 0), height - 1), min(max(column, 0), width - 1)

    grid = [[(" ", "")] * width for _ in range(height)]
    for start, end in zip(vertices, np.roll(vertices, -1, axis=0), strict=True):
        for fraction in np.linspace(0.0, 1.0, 4 * (width + height)):
            row, column = cell(start + fraction * (end - start))
            grid[row][column] = ("·", "grey50")
    if model.centres is not None:
        for centre in model.centres:
            if centre is not None:
                row, column = cell(np.asarray(centre))
                grid[row][column] = ("+", "yellow")
    if model.target is not None:
        row, column = cell(model.target)
        grid[row][column] = ("x", "bold red")
    if model.positions is not None:
        for index, (position, status) in enumerate(zip(model.positions, model.robots, strict=True)):
            row, column = cell(position)
            style = "dim red" if not status.alive else "bold magenta" if status.polled_now else "bold cyan"
            grid[row][column] = (robot_label(index), style)
    text = Text()
    for line in grid:
        for character, style in line:
            text.append(character, style)
        text.append("\n")
    text.rstrip()
    return text


WIDE = 100  # console columns from which the side-by-side layout fits
# Robot columns, widest set first: a console takes the first whose table fits its width.
ROBOT_COLUMNS = (
    ("robot", "links", "angle", "gV", "ubd", "ages", "polls", "sent", "recv", "last trigger"),
    ("robot", "links", "angle", "ubd", "polls", "sent", "recv", "last trigger"),
    ("robot", "links", "angle", "ubd", "polls", "sent"),
)


def robots_table(model: TeamModel, width: int) -> Table:
    """A row per robot with the widest set of :data:`ROBOT_COLUMNS` whose table fits ``width``
    console columns unsqueezed (narrow consoles get the essential ones)."""
    rows = [robot_cells(model, index) for index in range(min(len(model.robots), ROBOT_ROWS))]
    measuring = Console(width=10_000)  # measure unclamped: a console clamps to its own width
    for columns in ROBOT_COLUMNS:
        table = _robots_table(model, rows, columns)
        if measuring.measure(table).maximum <= width:
            break
    return table


def _robots_table(model: TeamModel, rows: list[dict[str, str | Text]], columns: tuple[str, ...]) -> Table:
    hidden = len(model.robots) - ROBOT_ROWS
    caption = (f"angles about each robot's own centre · links to predecessor|successor: ok or the latest fault of "
               f"the past {LINK_MEMORY_STEPS} steps · sent/recv: robot-to-robot messages/bytes · triggers: T1 ubd, "
               "T2 order+, T3 order-, unk unknown neighbour, every constant strategy")
    if hidden > 0:
        caption = f"... and {hidden} more robots · {caption}"
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 1), collapse_padding=True, pad_edge=False, expand=False,
                  caption=caption, caption_justify="left")
    for column in columns:
        table.add_column(column, justify="right", no_wrap=True,
                         max_width=REASON_WIDTH + 2 if column == "last trigger" else None,  # + its padding
                         overflow="ellipsis")
    for cells in rows:
        table.add_row(*(cells[column] for column in columns))
    return table


def robot_cells(model: TeamModel, index: int) -> dict[str, str | Text]:
    """Every robot column's cell for robot ``index``."""
    status = model.robots[index]
    return {
        "robot": f"r{index} {robot_label(index)}",
        "links": links_text(model, index),
        "angle": _degrees(status.angle),
        "gV": _degrees(status.midpoint),
        "ubd": _degrees(status.ubd, 3),
        "ages": f"{status.ages[0]},{status.ages[1]}" if status.ages else "-",
        "polls": str(status.polls),
        "sent": f"{status.sent[0]}/{model.size_text(status.sent[1])}",
        "recv": f"{status.received[0]}/{model.size_text(status.received[1])}",
        "last trigger": f"{reason_text(status.last_reason)} @{status.last_reason_step}" if status.last_reason else "-",
    }


def links_text(model: TeamModel, robot: int) -> Text:
    """``predecessor|successor`` link states of a live robot, coloured; "down" for a dead one."""
    if not model.robots[robot].alive:
        return Text("down", "bold red")
    count = len(model.robots)
    states = [model.link_state(robot, (robot + side) % count) for side in (-1, 1)]
    return Text("|").join(Text(state, LINK_STYLES.get(state, "bold red")) for state in states)


def traffic_table(model: TeamModel) -> Table:
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 1))
    for column in ("traffic", "messages", "bytes", "msg per sim s"):
        table.add_column(column, justify="right", no_wrap=True)
    seconds = max(model.time + model.scenario.control.dt, 1e-9)
    for category in CATEGORIES:
        messages, size = model.totals[category]
        if category == "estimation" and messages == 0:
            continue
        label = "robot-to-robot" if category == "robot" else category
        table.add_row(label, str(messages), model.size_text(size), f"{messages / seconds:.1f}")
    return table


def _degrees(value: float, digits: int = 1) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}°"


class Dashboard:
    """A rich renderable of a :class:`TeamModel`, laid out for the console it is drawn on."""

    def __init__(self, model: TeamModel) -> None:
        self.model = model

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        model = self.model
        scenario = model.scenario
        width = options.max_width
        control = scenario.control
        rate = model.steps_per_second() if model.live else 0.0
        pace = f"replay x{model.replay_speed:g}" if model.replay_speed else f"{rate:.0f} steps/s" if rate else ""
        header = Text.assemble(
            ("ringtrack ", "bold"),
            f"{scenario.name} · {len(model.robots)} robots · {control.strategy} strategy · "
            f"{scenario.estimation.mode} target · {model.clock} · ",
            (f"step {model.step}/{model.steps}", "bold"),
            f" · t = {model.time:.1f} s" + (f" · {pace}" if pace else "") + f" · {model.status}",
        )
        yield header
        # The map takes what the robot table and the header leave of the console height.
        rows_below = min(len(model.robots), ROBOT_ROWS) + 6
        room = (options.height or options.size.height) - rows_below - 2
        vertices = scenario.region.vertices
        aspect = np.ptp(vertices[:, 1]) / max(np.ptp(vertices[:, 0]), 1e-9)
        map_width = max(20, min(64, width // 2 - 2 if width >= WIDE else width - 2))
        map_height = int(min(max(round(map_width * aspect / 2.0), 8), max(room, 8), 28))
        map_width = int(max(20, min(map_width, round(2.0 * map_height / aspect))))
        saved, share = model.saved()
        side = Group(
            traffic_table(model),
            Text.assemble(("saved vs constant: ", "bold"), f"{saved} robot-to-robot messages ({share:.0%}), ",
                          f"polls {model.polls}"),
            Text.assemble(("Cerr ", "bold"), sparkline(list(model.cerr), 40),
                          f" {model.cerr[-1]:.2f}°" if model.cerr else ""),
            *(
                [Text.assemble(("Terr ", "bold"), sparkline(list(model.terr), 40), f" {model.terr[-1]:.3f} m")]
                if scenario.estimation.mode != "known" and model.terr else []
            ),
            *([energy_text(model.energy_j)] if model.energy_j else []),
            Text("map: digits robots (magenta: polled this step), x target, + estimates", "grey50"),
        )
        if width >= WIDE:
            layout = Table.grid(padding=(0, 2))
            layout.add_column(no_wrap=True)
            layout.add_column()
            layout.add_row(region_map(model, map_width, map_height), side)
            yield layout
        else:
            yield region_map(model, min(map_width, width), map_height)
            yield side
        yield robots_table(model, width)
