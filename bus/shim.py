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
        fate = self._fate(message) if isinstance(message, Request) else DELIVERED
        self.counter.count_sent(0 if fate.dropped else fate.copies)
        self._settle(message, fate)
        if fate.dropped:
            return False
        for _ in range(fate.copies):
            if fate.delay_s:
                loop = asyncio.get_running_loop()
                loop.call_later(fate.delay_s, self.participant.send, destination, message)
            else:
                self.participant.send(destination, message)
        return True

    def receive(self, delivery: Delivery) -> tuple[list[Delivery], bool]:
        """``(deliveries for the robot now, lost)``; a reply's fate applies on arrival."""
        message = delivery.message
        if not isinstance(message, (Request, Reply)) or delivery.released:
            if isinstance(message, (Request, Reply)):
                self.counter.count_delivered(1)
            return [delivery], False
        fate = self._fate(message) if isinstance(message, Reply) else DELIVERED
        self._settle(message, fate)
        if fate.dropped:
            return [], True
        copies = [Delivery(message, delivery.route, delivery.size, released=True)] * fate.copies
        if fate.delay_s:
            loop = asyncio.get_running_loop()
            for copy in copies:
                loop.call_later(fate.delay_s, self.participant.inbox.push, copy)
            return [], False
        self.counter.count_delivered(len(copies))
        return copies, False

    def _settle(self, message: Request | Reply, fate: Fate) -> None:
        """Count what ``fate`` does to ``message`` and report each fault to the monitor."""
        self.counter.count_fate(fate)
        for what in fate.faults:
            notice = FaultNotice(SCHEMA, self.participant.keys.run, message.step, message.kind, message.sender,
                                 message.receiver, what, fate.reason or "", fate.delay_s)
            self.participant.send(MONITOR, notice)
