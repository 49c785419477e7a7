"""The monitor's picture of a team: :class:`TeamModel`, updated one run-log record at a time.

The monitor feeds it live as it writes the log, ``ringtrack replay`` reads it back from a log in file
order, so both hold exactly the same thing; the dashboard (:mod:`tools.dashboard.dashboard`) only renders it.
Angles in degrees, counter-clockwise, about each robot's own centre; positions in metres.
"""

from __future__ import annotations

import copy
import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ringtrack.agents.laws import uncertainty_bound
from ringtrack.bus.faults import FAULTS, POLL_MESSAGES
from ringtrack.bus.keys import FUSION, MONITOR, WORLD, robot_index
from ringtrack.tools.runlog.derived import step_errors
from ringtrack.world.geometry import angle_of
from ringtrack.world.scenario import Scenario

HISTORY = 600  # steps of Cerr/Terr kept for the sparklines
CATEGORIES = ("robot", "world", "estimation")
LINK_MEMORY_STEPS = 10  # a fault stays on its link's cell for this many steps after the step it hit
FAULT_NAMES = {"duplicated": "dup", "delayed": "delay"}  # of link events; a drop is shown by its reason


def messages_saved(robots: int, steps: int, spent: int) -> tuple[int, float]:
    """Robot-to-robot messages saved against the constant strategy, which polls both neighbours every
    step (:data:`~ringtrack.bus.faults.POLL_MESSAGES` per robot per step), by a team that sent
    ``spent`` in ``steps`` steps, and as a fraction of the constant strategy's total."""
    constant = POLL_MESSAGES * robots * steps
    return constant - spent, (constant - spent) / constant if constant else 0.0


def startup_names(scenario: Scenario) -> list[str]:
    """Everyone a run of ``scenario`` starts with, the monitor included, in the order the start-up
    frame lists them: world, fusion centre, monitor, robots."""
    order = {WORLD: -3, FUSION: -2, MONITOR: -1}
    return sorted(scenario.participants(), key=lambda name: order.get(name, robot_index(name) or 0))


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
    # The latest step that named a centre: the robot's position, that centre (metres) and its offset
    # gV - theta (radians); angle, midpoint and ubd are derived from it and from ages when drawn.
    seen: tuple[list[float], list[float], float | None] | None = None


class TeamModel:
    """Everything the dashboard shows, updated one run-log record at a time."""

    def __init__(self, scenario: Scenario, clock: str, replay_speed: float | None = None, live: bool = True) -> None:
        self.scenario = scenario
        self.clock = clock
        self.replay_speed = replay_speed  # shown instead of the live rate when replaying
        self.live = live  # live: the rate shown is steps per wall second
        self._robots = [RobotStatus() for _ in range(scenario.robots)]
        self._derived = True  # angle, midpoint and ubd of every robot are up to date
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
        self.expected: list[str] = []  # participants the run starts with (shown until the first step)
        self.up: set[str] = set()  # of those, the ones whose liveliness token has been seen
        self.note = ""  # what the start-up is doing (spawn's frame, before the monitor is up)
        self.energy_j: dict[str, list[float]] = {}  # robot -> [transmit, receive] J, from the end record

    def add(self, record: dict) -> None:
        """Fold in one ``step``, ``event`` or ``end`` record of the run log (others change nothing)."""
        if record["type"] == "end":
            self.energy_j = dict(record.get("energy_j") or {})
        elif record["type"] == "step":
            self._add_step(record)
        elif record["type"] == "event" and record["event"] in FAULTS:
            name = record["reason"] if record["event"] == "dropped" else FAULT_NAMES[record["event"]]
            self.link_faults[frozenset((record["sender"], record["receiver"]))] = (name, record["step"])

    @property
    def robots(self) -> list[RobotStatus]:
        """Every robot as of the latest step, its angles derived now (only what is drawn is computed:
        a monitor folds in hundreds of steps a second and draws four frames)."""
        if not self._derived:
            params = self.scenario.control
            for status in self._robots:
                if status.seen is not None:
                    position, centre, offset = status.seen
                    theta = float(angle_of(np.asarray(position, dtype=float), centre))
                    status.angle = math.degrees(theta) % 360.0
                    status.midpoint = math.nan if offset is None else math.degrees(theta + offset) % 360.0
                if status.ages is not None:
                    status.ubd = math.degrees(uncertainty_bound(status.ages[0], status.ages[1], params))
            self._derived = True
        return self._robots

    def _add_step(self, record: dict) -> None:
        if self.first_step_at is None:
            self.first_step_at = time.monotonic()
        self.step, self.time = record["step"], record["time"]
        self.positions = np.asarray(record["positions"], dtype=float)
        self.target = np.asarray(record["target"], dtype=float)
        self.centres = record["centre"]
        live = set(record["live"])
        self.bytes_counted = record["sent_bytes"] is not None
        self._derived = False
        for index, status in enumerate(self._robots):
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
                status.seen = (record["positions"][index], centre, record["offset"][index])
            ages = record["ages"][index]
            if ages is not None:
                status.ages = (ages[0], ages[1])
        for category, (messages, size) in record["traffic"].items():
            self.totals[category][0] += messages
            self.totals[category][1] += size or 0
        cerr, terr = step_errors(record)
        self.cerr.append(cerr)
        self.terr.append(terr)

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
        """Robot-to-robot messages saved against the constant strategy so far (:func:`messages_saved`)."""
        return messages_saved(len(self.robots), self.step, self.totals["robot"][0])

    def com_bar_so_far(self) -> float:
        """Polls per robot per step over steps 1..k (Com-bar as if the run had converged now; the
        constant strategy's is 1), or NaN before the first step."""
        return self.polls / (len(self.robots) * self.step) if self.step else math.nan

    def steps_per_second(self) -> float:
        """Steps per wall second since the first step (live), or 0 before it."""
        if self.first_step_at is None or self.step < 2:
            return 0.0
        elapsed = time.monotonic() - self.first_step_at
        return (self.step - 1) / elapsed if elapsed > 0 else 0.0

    def summary_line(self) -> str:
        """The plain one-line summary used without a terminal."""
        if self.step == 0 and self.expected:
            return f"starting: {len(self.up)}/{len(self.expected)} participants up"
        robot, world = self.totals["robot"], self.totals["world"]
        saved, share = self.saved()
        cerr = f"{self.cerr[-1]:.2f}" if self.cerr else "-"
        terr = f", Terr {self.terr[-1]:.3f} m" if self.terr and not math.isnan(self.terr[-1]) and \
            self.scenario.estimation.mode != "known" else ""
        return (f"step {self.step}/{self.steps}: robot-to-robot {robot[0]} msgs {self.size_text(robot[1])} B "
                f"(saved {saved} = {share:.0%} vs constant), world {world[0]} msgs, polls {self.polls}, "
                f"Cerr {cerr} deg{terr}")
