"""The robot process: one :class:`agents.node.RobotNode` driven by messages from the bus.

It waits until the world, both ring neighbours (and the monitor, the fusion centre when there is
one) are up, declares itself ready, then reacts to every message; between its polls it sends no
robot-to-robot message at all. Its robot-to-robot traffic passes through the fault layer
(:class:`bus.shim.LinkShim`); a reply that will not come (dropped, out of range, its sender gone,
or, in realtime, later than ``reply_timeout``) never blocks it, nor, in realtime, does a fusion
centre's estimate later than ``ESTIMATE_SHARE * reply_timeout``. A robot that leaves (its
liveliness token goes) or comes back (the world's measurements say so) re-forms its ring. A robot
told it is outside the ring (restarted, woken after a freeze past the lease, or dropped by a lockstep
world that waited too long) shows whom it reaches, and every robot shows which robots outside its ring
it reaches (:mod:`bus.reach`), until the world re-admits them (:mod:`world.admission`). It ends on the
world's End, on a signal, or when the world is gone. Each process is a *life* of its robot id,
granted by the world as it joins (:mod:`bus.lives`); one that finds its id taken by a newer life (it
was frozen past the lease and the id rejoined) stops at once with :class:`bus.lives.Superseded`.
"""

from __future__ import annotations

import asyncio
import os
import signal
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec

from ringtrack.agents.node import BUFFERED_LIMIT, Outgoing, RobotNode
from ringtrack.bus.config import BusConfig
from ringtrack.bus.faults import cut_peers
from ringtrack.bus.identity import IdClaim, refuse_if_alive
from ringtrack.bus.keys import BROADCAST, MONITOR, WORLD, Keys, participants, robot_index
from ringtrack.bus.lives import NewerLife, Superseded, Voyage, ask_life, row_out, superseded_message
from ringtrack.bus.messages import Command, End, Measurement, Push, RangeReport, Reply, Request, Stats, encode
from ringtrack.bus.participant import Delivery, Interrupt, Participant, Posted, Presence, far_ahead
from ringtrack.bus.reach import ReachTokens
from ringtrack.bus.runtime import COUNTS_FOLDER_ENV, STOPPED, Interrupts, Role, Roster, next_events, perform
from ringtrack.bus.shim import LinkShim
from ringtrack.world.scenario import Scenario

# Realtime: the share of the reply timeout (one step period under spawn) a robot waits for the
# centre's estimate, leaving the rest of the step to poll and command about the last estimate.
ESTIMATE_SHARE = 0.5
FENCED = 2  # the exit code of a life replaced by a newer one of its robot id
# After the End a robot still takes in the robot-to-robot messages on their way to it (a neighbour's
# push of the last step travels on another link than the End) until none has come for this long...
LATE_QUIET_S = 0.1
LATE_LIMIT_S = 1.0  # ... and at most this long


@dataclass(frozen=True)
class Deadline(Posted):
    """What the robot waits for in ``step`` is due: the ``replies`` of its poll, the fusion
    centre's ``estimate`` (realtime), or the ``pushes`` of the previous step the world named."""

    step: int
    what: Literal["replies", "estimate", "pushes"]


async def run_robot(
    robot: int,
    scenario: Scenario,
    run: int,
    bus: BusConfig,
    interrupts: Interrupts,
    expect_monitor: bool = False,
    reply_timeout: float | None = None,
) -> int:
    """Run robot ``robot`` until the run ends; returns the exit code (0 done, 1 world lost, 130
    stopped). Raises :class:`bus.lives.Superseded` when a newer life of its id replaced it.

    ``reply_timeout`` (wall seconds) bounds how long a poll waits in realtime; None (lockstep) waits
    for every answer or an explicit loss, so results do not depend on timing.
    """
    node = RobotNode(robot, scenario, run)
    keys = Keys(run)
    link: RobotLink | None = None
    claim: IdClaim | None = None

    async def check_identity(participant: Participant) -> None:
        """Refuse to start as a robot that is alive already (before this one declares its token),
        then take the life the world grants."""
        await refuse_if_alive(participant)
        participant.live_as(await ask_life(participant))

    def claim_identity(participant: Participant) -> None:
        nonlocal claim
        claim = IdClaim(participant)

    async def main(participant: Participant, roster: Roster, events: list) -> int:
        nonlocal link
        link = RobotLink(participant, node, reply_timeout, expect_monitor)
        folder = os.environ.get(COUNTS_FOLDER_ENV)  # a supervisor's run folder, where a nemesis cuts links
        loop = asyncio.get_running_loop()
        if folder:
            shim = link.shim
            loop.add_signal_handler(signal.SIGUSR1, lambda: setattr(shim, "cut", cut_peers(Path(folder), robot)))
        try:
            assert claim is not None
            code = await _serve(link, roster, events, FenceCheck(bus, claim))
            if code == 0:
                await take_late_arrivals(link)
            return code
        finally:
            if folder:
                loop.remove_signal_handler(signal.SIGUSR1)
            link.reach.close()
            if claim is not None:
                claim.close()

    def stats(participant: Participant, code: int) -> Stats | None:
        """The robot's books; a replaced life sends them over a lifeboat itself (None: nothing left
        for :func:`bus.runtime.perform` to send)."""
        assert link is not None and claim is not None
        link.shim.release_held()
        notes = {"polls": node.polls, "probes": node.probes, "pushes": node.pushes_sent,
                 "pushes_waited_out": node.pushes_waited_out, "ignored_replies": node.ignored_replies,
                 "ignored_requests": node.ignored_requests, "rate_limited": node.rate_limited,
                 "id_collisions": len(claim.rivals), "superseded": int(code == FENCED)}
        books = participant.stats(final=True, faults=link.shim.counter.table(), notes=notes,
                                  energy_j=(link.shim.energy_j[0], link.shim.energy_j[1]))
        if code == FENCED and expect_monitor:
            FenceCheck(bus, claim).send_books(books)
            return None
        return books

    role = Role(
        name=node.name,
        needed=participants((node.predecessor, node.successor), node.mode == "centralized", expect_monitor),
        main=main,
        listen=(keys.inbox(node.name), keys.inbox(BROADCAST)),
        before_alive=check_identity,
        on_joined=claim_identity,
        stats=stats,
        linger_for=lambda code: {MONITOR} if expect_monitor and code not in (STOPPED, FENCED) else set(),
    )
    code = await perform(role, bus, keys, scenario.robots, interrupts)
    if code == FENCED:
        assert claim is not None
        raise Superseded(superseded_message(node.name, run, claim.life, claim.newer))
    return code


async def run_robots(
    robots: list[int],
    scenario: Scenario,
    run: int,
    bus: BusConfig,
    expect_monitor: bool = False,
    exit_with_parent: bool = False,
    reply_timeout: float | None = None,
) -> int:
    """Run several robots in this process, each its own Zenoh session and participant (own identity,
    own counts), sharing one event loop; returns the worst exit code."""
    interrupts = Interrupts(exit_with_parent)
    codes = await asyncio.gather(*(
        run_robot(robot, scenario, run, bus, interrupts, expect_monitor, reply_timeout)
        for robot in robots
    ))
    return max(codes)


class RobotLink:
    """Connects the node to the bus through the fault layer, turning losses into ``on_lost``."""

    def __init__(self, participant: Participant, node: RobotNode, reply_timeout: float | None,
                 expect_monitor: bool = False) -> None:
        self.participant = participant
        self.expect_monitor = expect_monitor  # the run has a monitor, which keeps everyone's books
        self.node = node
        self.reply_timeout = reply_timeout
        participant.window = lambda message: far_ahead(message, node.step)  # forged far-future steps
        self.shim = LinkShim(participant, node.scenario.faults, node.robot, node.reachable, node.distance,
                             realtime=reply_timeout is not None)
        self.outside = False  # told by the world that it is not in the ring
        self.held: list[Delivery] = []  # requests that came while outside, for the step it comes back at
        self.reach = ReachTokens(participant)
        self.deadlines: list[tuple[int, asyncio.TimerHandle]] = []  # (step, timer) of each armed Deadline

    def show_reach(self, alive: set[str]) -> None:
        """Hold a ``reach`` token for each participant in ``alive`` (their token is up) that the world
        needs to hear of before it re-admits a robot: every one while this robot is outside the ring,
        else the robots outside this robot's ring. Called only after a batch of events that may
        change who is alive, the ring or ``outside`` (:func:`_may_change_reach`)."""
        others = alive - {self.node.name}
        if not self.outside:
            others = {name for name in others if (robot := robot_index(name)) is not None
                      and robot < self.node.scenario.robots and robot not in self.node.alive}
        self.reach.hold(others)

    def measurement(self, measurement: Measurement) -> bool:
        """Note whether the world says this robot is outside the ring; False: not for the node."""
        if measurement.live is None or measurement.robot != self.node.robot:
            return True
        self.outside = measurement.robot not in measurement.live
        return not self.outside

    def send(self, outgoing: Outgoing) -> None:
        pending = deque(outgoing)
        while pending:
            destination, message = pending.popleft()
            if isinstance(message, Command):  # with the robot's own count of what its step put on the bus
                message = msgspec.structs.replace(message, robot_traffic=self.shim.take_traffic(message.step),
                                                  energy_j=self.shim.energy_through(message.step - 1))
            if not self.shim.send(destination, message) and (robot := robot_index(destination)) is not None:
                pending += self.node.on_lost(robot)
        if self.reply_timeout is None:
            return  # every answer and push comes, or its loss is known at once
        if any(isinstance(message, Request) for _, message in outgoing) and self.node.awaiting:  # opened a poll
            self.arm(self.reply_timeout, "replies")
        if any(isinstance(message, RangeReport) for _, message in outgoing):
            self.arm(ESTIMATE_SHARE * self.reply_timeout, "estimate")

    def arm(self, delay_s: float, what: Literal["replies", "estimate", "pushes"]) -> None:
        """Post a :class:`Deadline` for ``what`` of the current step in ``delay_s`` wall seconds."""
        timer = asyncio.get_running_loop().call_later(delay_s, self.participant.inbox.push,
                                                      Deadline(self.node.step, what))
        self.deadlines.append((self.node.step, timer))

    def cancel_passed_deadlines(self) -> None:
        """Cancel the deadlines of the steps the robot has left: :meth:`deadline` would ignore them,
        and each would wake the robot once more when it fell due (in lockstep, one per poll, seconds
        later). One that fell due already is still ignored there."""
        if self.deadlines and self.deadlines[0][0] < self.node.step:
            for step, timer in self.deadlines:
                if step < self.node.step:
                    timer.cancel()
            self.deadlines = [(step, timer) for step, timer in self.deadlines if step >= self.node.step]

    def deliver(self, delivery: Delivery) -> None:
        """Hand a message to the node through the fault layer. While outside the ring, the robot's
        step is far behind the world's: a neighbour's request for the step it comes back at may
        arrive before that step's measurement, and is held until then (the node would refuse a
        request that far ahead), at most ``BUFFERED_LIMIT`` of them."""
        message = delivery.message
        if isinstance(message, Measurement):
            was_outside = self.outside
            if not self.measurement(message):
                return
            if was_outside:
                self._deliver(delivery)
                held, self.held = self.held, []
                for request in held:
                    self._deliver(request)
                return
        elif isinstance(message, Request) and self.outside and len(self.held) < BUFFERED_LIMIT:
            self.held.append(delivery)
            return
        self._deliver(delivery)

    def _deliver(self, delivery: Delivery) -> None:
        deliveries, lost = self.shim.receive(delivery)
        message = delivery.message
        if lost and isinstance(message, Reply):
            self.send(self.node.on_lost(message.sender, message.nonce))
        if lost and isinstance(message, Push):
            self.send(self.node.on_push_lost(message.sender, message.step))
        for copy in deliveries:
            self.send(self.node.handle(copy.message))
            if isinstance(copy.message, Measurement) and self.reply_timeout is not None:
                self.cancel_passed_deadlines()
                if self.node.expected:  # the measurement opened a wait for the pushes the world named
                    self.arm(self.reply_timeout, "pushes")  # bounded like a poll

    def deadline(self, event: Deadline) -> None:
        if event.step != self.node.step:
            return  # the robot has left that step
        if event.what == "estimate":
            self.send(self.node.on_estimate_lost())
        elif event.what == "pushes":
            self.send(self.node.on_pushes_late())
        else:
            for neighbour in list(self.node.awaiting):
                self.send(self.node.on_lost(neighbour))


def _newest_measurement_only(events: list) -> list:
    """Drop measurements superseded by a newer one in the same batch (a robot that fell behind the
    realtime clock acts on the latest state; in lockstep a batch never holds two)."""
    steps = [event.message.step for event in events
             if isinstance(event, Delivery) and isinstance(event.message, Measurement)]
    if len(steps) < 2:
        return events
    newest = max(steps)
    return [event for event in events if not (isinstance(event, Delivery) and isinstance(event.message, Measurement)
                                              and event.message.step < newest)]


def _may_change_reach(event: object) -> bool:
    """Whether ``event`` may change whom a robot shows it reaches: a presence change, or a measurement
    carrying the live set (the world sends it only when the ring changes or the robot is outside)."""
    return isinstance(event, Presence) or (isinstance(event, Delivery) and isinstance(event.message, Measurement)
                                           and event.message.live is not None)


class FenceCheck:
    """When the world seems gone, ask it through a lifeboat (:func:`bus.lives.row_out`) whether a
    newer life of this robot's id was granted meanwhile: a process woken after a freeze past the
    lease learns it was replaced within a lease, though its own session may link again only later.
    A replaced life sends its books to the monitor through a lifeboat too (:meth:`send_books`)."""

    def __init__(self, bus: BusConfig, claim: IdClaim) -> None:
        self.bus = bus
        self.claim = claim
        self.task: asyncio.Future[None] | None = None

    def voyage(self, books: bytes | None = None) -> Voyage:
        participant = self.claim.participant
        return Voyage(self.bus, participant.keys.run, participant.name, self.claim.life, books)

    def start(self) -> None:
        """Start a check unless one is under way."""
        if self.task is None or self.task.done():
            self.task = asyncio.ensure_future(asyncio.to_thread(self._check))

    def under_way(self) -> bool:
        return self.task is not None and not self.task.done()

    def _check(self) -> None:
        if (newest := row_out(self.voyage())) is not None:
            self.claim.newer_life(newest)

    def send_books(self, stats: Stats) -> None:
        """Send a replaced life's final statistics to the monitor (its own session may not reach
        the monitor yet)."""
        row_out(self.voyage(encode(stats)))


def count_arrivals(link: RobotLink, events: list) -> None:
    """Take the robot-to-robot messages among ``events`` through the fault layer, counted as
    delivered or dropped by their fates, without handing them to the node (the run is over)."""
    for event in events:
        if isinstance(event, Delivery) and isinstance(event.message, (Request, Reply, Push)):
            link.shim.receive(event)


async def take_late_arrivals(link: RobotLink) -> None:
    """After the End, count (:func:`count_arrivals`) what still arrives until nothing has come for
    ``LATE_QUIET_S`` seconds, at most ``LATE_LIMIT_S``: a message put on the bus before the End
    counts as the engine counts it, not as lost because its receiver stopped first."""
    loop = asyncio.get_running_loop()
    until = loop.time() + LATE_LIMIT_S
    while loop.time() < until:
        events = await link.participant.events(timeout=min(LATE_QUIET_S, max(0.0, until - loop.time())))
        if not events:
            return
        count_arrivals(link, events)


async def _serve(link: RobotLink, roster: Roster, events: list, fence: FenceCheck) -> int:
    node = link.node
    reach_may_change = True  # shown once at the start
    while True:
        batch = _newest_measurement_only(events)
        for index, event in enumerate(batch):
            reach_may_change = reach_may_change or _may_change_reach(event)
            if isinstance(event, Delivery):
                link.deliver(event)
                if isinstance(event.message, End):
                    count_arrivals(link, batch[index + 1:])
                    return 0
            elif isinstance(event, Deadline):
                link.deadline(event)
            elif isinstance(event, Interrupt):
                return STOPPED
            elif isinstance(event, NewerLife):
                return FENCED
            elif isinstance(event, Presence):
                roster.update(event)
                if event.name == WORLD and event.kind == "alive" and not event.up:
                    fence.start()
                robot = robot_index(event.name)
                if event.kind == "alive" and not event.up and robot in node.alive - {node.robot}:
                    # The team starts whole; a robot that leaves (crash) is dropped at once. One that
                    # comes back (restart) is announced by the world with the step it rejoins at.
                    link.send(node.set_alive(node.alive - {robot}))
        if reach_may_change:
            link.show_reach(roster.alive)
            reach_may_change = False
        if roster.gone_for_good(WORLD) and not fence.under_way():
            return 1  # the world went away without ending the run
        events = await next_events(link.participant, roster)
