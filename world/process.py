"""The world process: owns the clock and the true state, serves measurements, integrates motion.

Clocks:

* ``lockstep``: publish step k (a Tick to the monitor, a Measurement to every robot), wait for every
  robot's Command for k, integrate, publish k + 1. Deterministic for a scenario and seed.
* ``realtime``: step every ``dt / rate`` wall seconds, integrating each robot's latest goal
  whatever step it was computed for.

The world starts once every robot (and the monitor, when one is expected) is ready, and ends the
run with an :class:`~bus.messages.End` to everyone. A robot that disappears (or, in lockstep, stays
silent for ``lockstep_wait`` seconds) leaves the live set (its neighbours re-form the ring around it)
and stays where it stopped; one that comes back is re-admitted by a handshake once it and its future
ring neighbours reach one another (:mod:`world.admission`), placed midway between them
(:meth:`world.state.WorldState.rejoin`).
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ringtrack.bus.config import BusConfig, announce_endpoints
from ringtrack.bus.keys import BROADCAST, MONITOR, WORLD, Keys, participants, robot_index, robot_name
from ringtrack.bus.lives import LifeRegistry
from ringtrack.bus.messages import SCHEMA, Command, Digest, DigestEntry, End, EndReason, Tick, digest_entries
from ringtrack.bus.participant import Delivery, Interrupt, Participant, Presence
from ringtrack.bus.reach import Reach, ReachTokens, ReachWatch
from ringtrack.bus.runtime import STOPPED, Interrupts, Role, Roster, perform
from ringtrack.world.admission import Admission
from ringtrack.world.backlog import Backlog, Measurements, step_entries
from ringtrack.world.metrics import CerrSource
from ringtrack.world.scenario import Scenario
from ringtrack.world.state import WorldState

log = logging.getLogger("ringtrack.world")

Clock = Literal["lockstep", "realtime"]


@dataclass(frozen=True)
class WorldOptions:
    """How the world runs: at most ``steps`` steps (fewer with ``until_converged``: it ends after the
    first step whose Cerr is below the threshold), the ``clock``, the realtime ``rate`` factor
    (simulated seconds per wall second), whether a monitor must be ready before step 1, whether to send
    it a :class:`~bus.messages.Digest` each step, and where to write the endpoints it listens on
    (``announce``) so others can connect."""

    steps: int
    clock: Clock = "lockstep"
    rate: float = 1.0
    expect_monitor: bool = False
    announce: Path | None = None
    until_converged: bool = False
    lockstep_wait: float = 10.0  # s (--lockstep-wait); lockstep: a robot silent this long in one step is gone
    digest: bool = False  # lockstep: report to the monitor in Digests of the world's own links (no audit)
    cerr: CerrSource = "memory"  # the Cerr that decides convergence: the scenario's strategy's (Strategy.cerr)
    monitor_grace: float = 0.0  # s (--monitor-grace); > 0: hold the run this long for a lost monitor to come back


WAIT_NOTICE_S = 2.0  # lockstep: name the robots a step waits for once it has waited this long
DIGEST_PERIOD_S = 0.05  # lockstep: a step's digest entry waits at most this long for later steps to join it


class RunStopped(Exception):
    """The run cannot go on: ``reason`` says why."""

    def __init__(self, reason: EndReason) -> None:
        super().__init__(reason.value)
        self.reason = reason


async def run_world(scenario: Scenario, seed: int, run: int, bus: BusConfig, options: WorldOptions,
                    exit_with_parent: bool = False) -> int:
    """Serve one run; returns the process exit code (0 done, 1 failed, 130 interrupted)."""
    keys = Keys(run)
    team = participants(range(scenario.robots), centralized=False, monitor=options.expect_monitor) - {WORLD}
    everyone = scenario.participants(monitor=options.expect_monitor)
    admission = Admission({name for name in everyone if robot_index(name) is None}, scenario.robots)
    tokens: list[ReachTokens] = []
    registries: list[LifeRegistry] = []

    async def main(participant: Participant, roster: Roster, _held: list) -> int:
        world = WorldState(scenario, seed, run, options.steps, options.cerr)
        began = time.perf_counter()
        step_once = functools.partial(_lockstep, wait_s=options.lockstep_wait) if options.clock == "lockstep" \
            else _realtime
        reason, code = EndReason.DONE, 0
        period = scenario.control.dt / options.rate
        start = asyncio.get_running_loop().time()
        watch = ReachWatch(participant)
        digests = Digests(participant) if options.digest else None
        context = Context(participant, world, roster, admission, tokens[0], digests, options.expect_monitor,
                          options.monitor_grace, Backlog(participant) if options.monitor_grace > 0 else None)
        try:
            for index in range(options.steps):
                context.measurements, context.commands = [], []
                await step_once(context, start + (index + 1) * period)
                if digests is not None or context.backlog is not None:  # else no step leaves an entry
                    entries = step_entries(world.step, context.tick, context.measurements, context.commands,
                                           scenario.robots)
                    if digests is not None:
                        digests.add(entries, asyncio.get_running_loop().time())
                    if context.backlog is not None:
                        context.backlog.add(entries)
                admit(context)
                refuse_empty_ring(world)
                converged = options.until_converged and world.converged()
                world.advance()
                if converged:
                    reason = EndReason.CONVERGED
                    break
                if context.monitor_away_since is not None:
                    start += await hold_for_monitor(context)  # a realtime schedule resumes where it was
        except RunStopped as stop:
            reason, code = stop.reason, STOPPED if stop.reason.interrupted else 1
        finally:
            watch.close()
            if digests is not None:
                digests.flush()
        wall = time.perf_counter() - began
        last = world.step - 1
        participant.send(BROADCAST, End(SCHEMA, run, last, reason, wall))
        said = reason.value if reason.interrupted else reason.text(world.step)
        log.info("run %s after %d steps in %.2f s (%.0f steps/s)", said, last, wall, last / wall if wall else 0.0)
        return code

    async def grant_lives(participant: Participant) -> None:
        """Answer robots' life queries (:mod:`bus.lives`) before anyone can see the world alive."""
        registries.append(LifeRegistry(participant))

    def on_joined(participant: Participant) -> None:
        tokens.append(ReachTokens(participant))
        if options.announce is not None:
            announce_endpoints(participant.session, options.announce)

    role = Role(
        name=WORLD,
        needed=everyone - {WORLD},
        main=main,
        listen=(keys.inbox(WORLD),),
        start_on="ready",
        announces_ready=False,
        before_alive=grant_lives,
        on_joined=on_joined,
        on_gathering=lambda roster: tokens[0].hold(alive_robots(roster, scenario.robots)),
        linger_for=lambda code: team,
    )
    try:
        return await perform(role, bus, keys, scenario.robots, Interrupts(exit_with_parent))
    finally:
        for held in tokens:
            held.close()
        for registry in registries:
            registry.close()


@dataclass
class Context:
    """What a step of the world works with: its participant, the true state, who is alive, the
    re-admission handshake and the ``reach`` tokens the world holds (one per robot it sees alive)."""

    participant: Participant
    world: WorldState
    roster: Roster
    admission: Admission
    tokens: ReachTokens
    digests: Digests | None = None  # lockstep without audit: what the world tells the monitor, in digests
    expect_monitor: bool = False  # the run has a monitor: the world ends the run when it goes...
    monitor_grace: float = 0.0  # ... unless this is > 0 (s): then it holds the run that long for it to come back
    backlog: Backlog | None = None  # with a grace: the steps kept for a monitor that comes back
    monitor_away_since: float | None = None  # loop time at which the monitor went away (None: it is here)
    # This step's tick, measurements published (robot, payload bytes) and commands received (with
    # their payload bytes): what a digest entry tells the monitor.
    tick: Tick | None = None
    measurements: Measurements = field(default_factory=list)
    commands: list[tuple[Command, int]] = field(default_factory=list)


def alive_robots(roster: Roster, robots: int) -> set[str]:
    """The names of the team's robots whose ``alive`` token is up."""
    return {name for name in roster.alive if (robot := robot_index(name)) is not None and robot < robots}


def admit(context: Context) -> None:
    """At the end of a step: bring back, from the next step, every robot outside the ring that the
    handshake admits (:class:`world.admission.Admission`)."""
    world = context.world
    for robot in context.admission.admit(world.live | world.rejoining, context.roster.alive):
        world.rejoin(robot)
        log.info("robot r%d rejoins at step %d: it and its ring neighbours reach one another; placed between them",
                 robot, world.step + 1)


def tell_outside(context: Context, robot: int) -> None:
    """Tell robot ``robot`` (alive, not in the ring) that it is outside: its measurement of this
    step with the live set, which leaves it out; it then shows whom it reaches (:mod:`bus.reach`)."""
    measurement = context.world.measurement(robot)
    context.measurements.append((robot, context.participant.send(robot_name(robot), measurement)))


def refuse_empty_ring(world: WorldState) -> None:
    """Raise :class:`RunStopped` once no robot is left in the ring (they all crashed, or all quit on
    a forged End): such a run ends as failed, never as done or converged."""
    if not world.live and not world.rejoining:
        raise RunStopped(EndReason.RING_EMPTY)


def _publish(context: Context) -> None:
    """Publish the step: each live robot's measurement (noted in the context) and the tick, to the
    monitor at once or, with digests, in the step's digest entry."""
    participant, world = context.participant, context.world
    live = list(world.ring)
    context.tick = world.tick(live)
    if context.digests is None:
        participant.send(MONITOR, context.tick)
    for robot in live:
        context.measurements.append((robot, participant.send(robot_name(robot), world.measurement(robot))))


class Digests:
    """What the world tells the monitor of its steps in lockstep: per step a :class:`DigestEntry`
    (its tick, the measurements published, the commands received with their payload bytes), sent in
    a :class:`Digest` once ``digest_entries`` are waiting, once the oldest has waited
    ``DIGEST_PERIOD_S`` (checked as steps end and while one waits for commands), and before the End.
    A team of six at hundreds of steps a second thus sends one digest every ten steps instead of a
    tick and a digest every step; the monitor's view lags by at most ``DIGEST_PERIOD_S``. Times
    (``now``) are the event loop's clock, in seconds."""

    def __init__(self, participant: Participant) -> None:
        self.participant = participant
        self.limit = digest_entries(participant.robots)
        self.pending: list[DigestEntry] = []
        self.due: float | None = None  # loop time by which the pending entries leave

    def add(self, entries: list[DigestEntry], now: float) -> None:
        """The entries of a step (:func:`world.backlog.step_entries`), ended at ``now``."""
        self.pending += entries
        if self.due is None:
            self.due = now + DIGEST_PERIOD_S
        if len(self.pending) >= self.limit:
            self.flush()
        self.send_due(now)

    def send_due(self, now: float) -> None:
        """Send the pending entries if the oldest has waited its time by ``now``."""
        if self.due is not None and now >= self.due:
            self.flush()

    def flush(self) -> None:
        """Send every pending entry, ``limit`` to a digest."""
        run = self.participant.keys.run
        for first in range(0, len(self.pending), self.limit):
            self.participant.send(MONITOR, Digest(SCHEMA, run, self.pending[first:first + self.limit]))
        self.pending, self.due = [], None


def _handle(event: object, context: Context) -> None:
    """Apply one event to the world, adding every command received to ``context.commands``; raise
    :class:`RunStopped` when the run must end.

    A robot whose process goes away (a crash, or a freeze past the lease: its liveliness token is
    withdrawn) leaves the live set and stays where it is; one whose token comes up outside the ring
    (a restart, a wake-up) is told it is outside, and comes back by the handshake of :func:`admit`.
    A run with a monitor ends when the monitor goes (:attr:`EndReason.MONITOR_LOST`)."""
    world, participant, roster = context.world, context.participant, context.roster
    if isinstance(event, Delivery) and isinstance(event.message, Command):
        context.commands.append((event.message, event.size))
        if world.possible(event.message):
            world.accept(event.message)
        else:
            participant.counter.count_rejected("value")
    elif isinstance(event, Reach):
        context.admission.update(event)
    elif isinstance(event, Interrupt):
        raise RunStopped(EndReason.interrupted_by(event.reason))
    elif isinstance(event, Presence) and event.kind == "alive":
        roster.update(event)
        if event.name == MONITOR and context.expect_monitor:
            monitor_came_or_went(context, event.up)
        context.tokens.hold(alive_robots(roster, world.scenario.robots))
        robot = robot_index(event.name)
        if robot is None or robot >= world.scenario.robots:
            return
        if not event.up and robot in world.live | world.rejoining:
            world.leave(robot)
            log.warning("robot %s left at step %d; %d robots go on", event.name, world.step, len(world.live))
        elif event.up and robot not in world.live | world.rejoining:
            tell_outside(context, robot)
            log.info("robot %s is back at step %d, outside the ring until it and its ring neighbours reach one "
                     "another", event.name, world.step)
    elif isinstance(event, Presence):
        roster.update(event)


def monitor_came_or_went(context: Context, up: bool) -> None:
    """The monitor went away (``up`` False): end the run, or, with a grace, note when (the run is
    held after this step: :func:`hold_for_monitor`). A monitor came (back): send it the steps kept
    for it (:mod:`world.backlog`), whose entries then no ordinary digest carries again."""
    loop = asyncio.get_running_loop()
    if not up and context.backlog is None:
        log.error("the monitor went away at step %d (crashed, killed or cut off): nobody keeps the run's log "
                  "and books; ending the run", context.world.step)
        raise RunStopped(EndReason.MONITOR_LOST)
    if not up:
        context.monitor_away_since = context.monitor_away_since or loop.time()
        log.warning("the monitor went away at step %d; the run holds for up to %g s for it to come back",
                    context.world.step, context.monitor_grace)
    elif context.backlog is not None and context.monitor_away_since is not None:
        if context.digests is not None:
            context.digests.pending, context.digests.due = [], None  # in the backlog: replayed, not digested again
        replayed = context.backlog.replay()
        log.warning("the monitor is back after %.1f s; %d step entries replayed to it", loop.time()
                    - context.monitor_away_since, replayed)
        context.monitor_away_since = None


async def hold_for_monitor(context: Context) -> float:
    """Hold the run between two steps until the monitor is back (then return the seconds held) or
    ``monitor_grace`` seconds after it went away (then raise :class:`RunStopped` with
    :attr:`EndReason.MONITOR_LOST`)."""
    loop = asyncio.get_running_loop()
    held_from = loop.time()
    while (away_since := context.monitor_away_since) is not None:
        if loop.time() >= away_since + context.monitor_grace:
            log.error("the monitor went away at step %d and did not come back within --monitor-grace %g s: nobody "
                      "keeps the run's log and books; ending the run", context.world.step, context.monitor_grace)
            raise RunStopped(EndReason.MONITOR_LOST)
        for event in await context.participant.events(until=away_since + context.monitor_grace):
            _handle(event, context)
    return loop.time() - held_from


async def _lockstep(context: Context, deadline: float, wait_s: float = 10.0) -> None:
    """Publish the step and wait for every live robot's command for it: after ``WAIT_NOTICE_S`` the
    world says which robots it waits for, and after ``wait_s`` (wall seconds, ``--lockstep-wait``) it
    treats those still silent as gone (a frozen process whose liveliness lease has not run out yet),
    so one robot cannot hang the team; such a robot is told it is outside the ring."""
    world, participant = context.world, context.participant
    loop = asyncio.get_running_loop()
    started, noticed = loop.time(), False
    _publish(context)
    while not world.commanded.issuperset(world.live):
        waited = loop.time() - started
        if waited >= wait_s:
            for robot in sorted(world.live - world.commanded):
                world.leave(robot)
                tell_outside(context, robot)
                log.warning("lockstep step %d: r%d sent no command within --lockstep-wait %g s; treated as gone, %d "
                            "robots go on", world.step, robot, wait_s, len(world.live))
            return
        if waited >= WAIT_NOTICE_S and not noticed:
            noticed = True
            log.warning("lockstep step %d waits for %s", world.step,
                        ", ".join(f"r{robot}" for robot in sorted(world.live - world.commanded)))
        next_check = wait_s if noticed else min(wait_s, WAIT_NOTICE_S)
        until, digests = started + next_check, context.digests
        if digests is not None and digests.due is not None:
            until = min(until, digests.due)  # the monitor sees the steps before one that waits long
        for event in await participant.events(until=until):
            _handle(event, context)
        if digests is not None:
            digests.send_due(loop.time())


async def _realtime(context: Context, deadline: float) -> None:
    """Publish the step and take whatever commands arrive until ``deadline`` (loop time: the start
    of the run plus ``step * dt / rate``, so the schedule does not drift)."""
    loop = asyncio.get_running_loop()
    _publish(context)
    while deadline > loop.time():
        for event in await context.participant.events(until=deadline):
            _handle(event, context)
