"""The fault layer a robot process puts between its protocol and the bus (see :mod:`bus.faults`)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from ringtrack.bus.faults import DELIVERED, Fate, FaultCounter, FaultPlan
from ringtrack.bus.keys import MONITOR
from ringtrack.bus.messages import SCHEMA, FaultNotice, Message, Reply, Request
from ringtrack.bus.participant import Delivery, Participant


class LinkShim:
    """Applies a :class:`FaultPlan` to one robot's robot-to-robot traffic and counts what it does.

    ``send`` settles the fate of the robot's own requests (False: dropped, no answer will come);
    ``receive`` settles the fate of replies to it (``lost``: dropped) and counts deliveries of
    requests. Delayed messages are published, or handed back to the robot, after their delay. Every
    dropped, duplicated or delayed message is reported to the monitor in a ``FaultNotice``;
    ``reachable(robot)`` says whether a neighbour is within communication range this step.
    """

    def __init__(self, participant: Participant, plan: FaultPlan, robot: int,
                 reachable: Callable[[int], bool]) -> None:
        self.participant = participant
        self.plan = plan
        self.robot = robot
        self.reachable = reachable
        self.counter = FaultCounter()

    def _fate(self, message: Request | Reply) -> Fate:
        if isinstance(message, Request) and not self.reachable(message.receiver):
            return Fate(dropped=True, reason="range")
        return self.plan.fate(message.kind, message.sender, message.receiver, message.step)

    def send(self, destination: str, message: Message) -> bool:
        """Publish ``message``; for a request, its fate applies. Returns False if it was dropped."""
        if not isinstance(message, (Request, Reply)):
            self.participant.send(destination, message)
            return True
        self.counter.counts["sent"] += 1
        fate = self._fate(message) if isinstance(message, Request) else DELIVERED
        if fate.dropped:
            self._record("dropped", message, fate)
            return False
        for _ in range(fate.copies):
            if fate.delay_s:
                loop = asyncio.get_running_loop()
                loop.call_later(fate.delay_s, self.participant.send, destination, message)
            else:
                self.participant.send(destination, message)
        self._note_extras(message, fate)
        return True

    def receive(self, delivery: Delivery) -> tuple[list[Delivery], bool]:
        """``(deliveries for the robot now, lost)``; a reply's fate applies on arrival."""
        message = delivery.message
        if not isinstance(message, (Request, Reply)) or delivery.released:
            if isinstance(message, (Request, Reply)):
                self.counter.counts["delivered"] += 1
            return [delivery], False
        fate = self._fate(message) if isinstance(message, Reply) else DELIVERED
        if fate.dropped:
            self._record("dropped", message, fate)
            return [], True
        self._note_extras(message, fate)
        copies = [Delivery(message, delivery.route, delivery.size, released=True)] * fate.copies
        if fate.delay_s:
            loop = asyncio.get_running_loop()
            for copy in copies:
                loop.call_later(fate.delay_s, self.participant.inbox.push, copy)
            return [], False
        self.counter.counts["delivered"] += len(copies)
        return copies, False

    def _note_extras(self, message: Request | Reply, fate: Fate) -> None:
        if fate.copies > 1:
            self._record("duplicated", message, fate)
        if fate.delay_s:
            self._record("delayed", message, fate)

    def _record(self, what: str, message: Request | Reply, fate: Fate) -> None:
        self.counter.counts[what] += fate.copies - 1 if what == "duplicated" else 1
        if fate.reason:
            self.counter.reasons[fate.reason] += 1
        notice = FaultNotice(SCHEMA, self.participant.keys.run, message.step, message.kind, message.sender,
                             message.receiver, what, fate.reason or "", fate.delay_s)
        self.participant.send(MONITOR, notice)
