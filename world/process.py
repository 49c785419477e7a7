"""The world process: owns the clock and the true state, serves measurements, integrates motion.

Clocks:

* ``lockstep``: publish step k (a Tick to the monitor, a Measurement to every robot), wait for every
  robot's Command for k, integrate, publish k + 1. Deterministic for a scenario and seed.
* ``realtime``: step every ``dt / rate`` wall seconds, integrating each robot's latest goal
  whatever step it was computed for.

The world starts once every robot (and the monitor, when one is expected) is ready, and ends the
run with an :class:`~bus.messages.End` to everyone. A robot that disappears leaves the live set (its
neighbours re-form the ring around it) and stays where it stopped; one that comes back rejoins,
placed midway between its live ring neighbours (:meth:`world.state.WorldState.rejoin`).
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ringtrack.bus.config import BusConfig, announce_endpoints
from ringtrack.bus.keys import BROADCAST, MONITOR, WORLD, Keys, participants, robot_index, robot_name
from ringtrack.bus.messages import SCHEMA, Command, Digest, End
from ringtrack.bus.participant import Delivery, Interrupt, Participant, Presence
from ringtrack.bus.runtime import STOPPED, Interrupts, Role, Roster, perform
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
    lockstep_wait: float = 10.0  # s; lockstep: a live robot silent this long in one step is treated as gone
    digest: bool = False  # lockstep: send the monitor a Digest of the world's own links each step (no audit)


WAIT_NOTICE_S = 2.0  # lockstep: name the robots a step waits for once it has waited this long


class RunStopped(Exception):
    """The run cannot go on; the message says why."""


async def run_world(scenario: Scenario, seed: int, run: int, bus: BusConfig, options: WorldOptions,
                    exit_with_parent: bool = False) -> int:
    """Serve one run; returns the process exit code (0 done, 1 failed, 130 interrupted)."""
    keys = Keys(run)
    team = participants(range(scenario.robots), centralized=False, monitor=options.expect_monitor) - {WORLD}

    async def main(participant: Participant, roster: Roster, _held: list) -> int:
        world = WorldState(scenario, seed, run, options.steps)
        began = time.perf_counter()
        step_once = functools.partial(_lockstep, wait_s=options.lockstep_wait) if options.clock == "lockstep" \
            else _realtime
        reason, code = "done", 0
        period = scenario.control.dt / options.rate
        start = asyncio.get_running_loop().time()
        try:
            for index in range(options.steps):
                commands: list[tuple[Command, int]] = []
                measurements = await step_once(participant, world, roster, start + (index + 1) * period, commands)
                if options.digest:
                    send_digest(participant, world.step, measurements, commands)
                refuse_empty_ring(world)
                converged = options.until_converged and world.converged()
                world.advance()
                if converged:
                    reason = "converged"
                    break
        except RunStopped as stop:
            reason, code = str(stop), STOPPED if str(stop).startswith("interrupted") else 1
        wall = time.perf_counter() - began
        last = world.step - 1
        participant.send(BROADCAST, End(SCHEMA, run, last, reason, wall))
        log.info("run %s after %d steps in %.2f s (%.0f steps/s)", reason, last, wall, last / wall if wall else 0.0)
        return code

    def on_joined(participant: Participant) -> None:
        if options.announce is not None:
            announce_endpoints(participant.session, options.announce)

    role = Role(
        name=WORLD,
        needed=participants(range(scenario.robots), scenario.estimation.mode == "centralized",
                            options.expect_monitor) - {WORLD},
        main=main,
        listen=(keys.inbox(WORLD),),
        start_on="ready",
        announces_ready=False,
        on_joined=on_joined,
        linger_for=lambda code: team,
    )
    return await perform(role, bus, keys, scenario.robots, Interrupts(exit_with_parent))


def refuse_empty_ring(world: WorldState) -> None:
    """Raise :class:`RunStopped` once no robot is left in the ring (they all crashed, or all quit on
    a forged End): such a run ends as failed, never as done or converged."""
    if not world.live and not world.rejoining:
        raise RunStopped(f"every robot left the ring by step {world.step}")


Measurements = list[tuple[int, int]]  # (robot, payload bytes) of the measurements of a step


def _publish(participant: Participant, world: WorldState) -> Measurements:
    live = sorted(world.live)
    participant.send(MONITOR, world.tick(live))
    return [(robot, participant.send(robot_name(robot), world.measurement(robot))) for robot in live]


def send_digest(participant: Participant, step: int, measurements: Measurements,
                commands: list[tuple[Command, int]]) -> None:
    """Tell the monitor what the world published (``measurements``) and received (``commands``, with
    their payload bytes) in ``step``, in digests of at most one command per robot of the team."""
    chunk = participant.robots
    participant.send(MONITOR, Digest(SCHEMA, participant.keys.run, step, measurements, commands[:chunk]))
    for first in range(chunk, len(commands), chunk):
        participant.send(MONITOR, Digest(SCHEMA, participant.keys.run, step, [], commands[first:first + chunk]))


def _handle(event: object, world: WorldState, roster: Roster, participant: Participant,
            commands: list[tuple[Command, int]]) -> None:
    """Apply one event to the world, adding every command received to ``commands``; raise
    :class:`RunStopped` when the run must end.

    A robot whose process goes away (a crash: its liveliness token is withdrawn) leaves the live
    set and stays where it is; one that declares itself ready again (a restart) rejoins."""
    if isinstance(event, Delivery) and isinstance(event.message, Command):
        commands.append((event.message, event.size))
        if world.possible(event.message):
            world.accept(event.message)
        else:
            participant.counter.count_rejected("value")
    elif isinstance(event, Interrupt):
        raise RunStopped(f"interrupted ({event.reason})")
    elif isinstance(event, Presence):
        roster.update(event)
        robot = robot_index(event.name)
        if robot is None:
            return
        if event.kind == "alive" and not event.up and robot in world.live | world.rejoining:
            world.leave(robot)
            log.warning("robot %s left at step %d; %d robots go on", event.name, world.step, len(world.live))
        elif event.kind == "ready" and event.up and robot not in world.live | world.rejoining:
            world.rejoin(robot)
            log.info("robot %s rejoins at step %d, placed between its ring neighbours", event.name, world.step + 1)


async def _lockstep(participant: Participant, world: WorldState, roster: Roster, deadline: float,
                    commands: list[tuple[Command, int]], wait_s: float = 10.0) -> Measurements:
    """Publish the step and wait for every live robot's command for it: after ``WAIT_NOTICE_S`` the
    world says which robots it waits for, and after ``wait_s`` (wall seconds) it treats those still
    silent as gone (a frozen process whose liveliness lease has not run out yet), so one robot
    cannot hang the team. Returns the step's measurements; every command received goes to ``commands``."""
    loop = asyncio.get_running_loop()
    started, noticed = loop.time(), False
    measurements = _publish(participant, world)
    while not world.commanded.issuperset(world.live):
        waited = loop.time() - started
        if waited >= wait_s:
            for robot in sorted(world.live - world.commanded):
                world.leave(robot)
                log.warning("robot r%d sent no command for step %d in %.0f s: treated as gone; %d robots go on",
                            robot, world.step, wait_s, len(world.live))
            return measurements
        if waited >= WAIT_NOTICE_S and not noticed:
            noticed = True
            log.warning("lockstep step %d waits for %s", world.step,
                        ", ".join(f"r{robot}" for robot in sorted(world.live - world.commanded)))
        next_check = wait_s if noticed else min(wait_s, WAIT_NOTICE_S)
        for event in await participant.events(max(0.01, next_check - waited)):
            _handle(event, world, roster, participant, commands)
    return measurements


async def _realtime(participant: Participant, world: WorldState, roster: Roster, deadline: float,
                    commands: list[tuple[Command, int]]) -> Measurements:
    """Publish the step and take whatever commands arrive until ``deadline`` (loop time: the start
    of the run plus ``step * dt / rate``, so the schedule does not drift). Returns the step's
    measurements; every command received goes to ``commands``."""
    loop = asyncio.get_running_loop()
    measurements = _publish(participant, world)
    while (remaining := deadline - loop.time()) > 0:
        for event in await participant.events(remaining):
            _handle(event, world, roster, participant, commands)
    return measurements
