"""The fault layer a robot process puts between its protocol and the bus (see :mod:`bus.faults`)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from ringtrack.bus.faults import DELIVERED, Fate, FaultCounter, FaultPlan, published_copies
from ringtrack.bus.keys import MONITOR
from ringtrack.bus.messages import (
    ROBOT_TRAFFIC_KINDS,
    SCHEMA,
    FaultNotice,
    Message,
    Push,
    Reply,
    Request,
    RobotMessage,
    RobotTraffic,
    encode,
)
from ringtrack.bus.participant import Delivery, Participant
from ringtrack.bus.radio import airtime_s, message_bits, receive_energy, transmit_energy

REQUEST, REPLY, PUSH = (ROBOT_TRAFFIC_KINDS.index(kind) for kind in ("request", "reply", "push"))


class LinkShim:
    """Applies a :class:`FaultPlan` to one robot's robot-to-robot traffic and counts what it does.

    ``send`` settles the fate of the robot's own requests (False: dropped, no answer will come);
    ``receive`` settles the fate of replies and pushes to it (``lost``: dropped) and counts
    deliveries of requests. Delayed messages are published, or handed back to the robot, after their delay. Every
    dropped, duplicated or delayed message is reported to the monitor in a ``FaultNotice``;
    ``reachable(robot)`` says whether a neighbour is within communication range this step and
    ``distance(robot, step)`` how far it was at the start of ``step`` (metres).

    ``energy_j`` is the radio energy of the robot's robot-to-robot traffic (:mod:`bus.radio`),
    transmit and receive: every copy it puts on the air costs transmission over the link's length
    (a request lost on the way out was still sent once), every copy handed to the robot reception.
    In ``realtime``, with a radio model other than the ideal one, each copy also takes its airtime
    (``latency + 8 bytes / bandwidth``) to arrive.
    """

    def __init__(self, participant: Participant, plan: FaultPlan, robot: int,
                 reachable: Callable[[int], bool], distance: Callable[[int, int], float],
                 realtime: bool = False) -> None:
        self.participant = participant
        self.plan = plan
        self.robot = robot
        self.reachable = reachable
        self.distance = distance
        self.realtime = realtime
        self.counter = FaultCounter()
        self.cut: frozenset[int] = frozenset()  # robots a nemesis has cut this one off from (bus.faults.cut_peers)
        self.energy_j = [0.0, 0.0]
        # The same energy by the step each message is stamped with, (transmit, receive) per copy,
        # until energy_through folds it into the settled total.
        self._step_energy: dict[int, tuple[list[float], list[float]]] = {}
        self._settled_j = [0.0, 0.0]
        # What the robot's steps have put on the bus since it last commanded (take_traffic): its
        # requests by nonce, as [step, peer, copies published, bytes, bytes of the peer's reply once
        # one came], and its pushes as (step, row).
        self._requests: dict[int, list[int]] = {}
        self._pushes: list[tuple[int, RobotTraffic]] = []
        # Delayed copies not yet published, by a running key: (their timer, what publishes them).
        self._held: dict[int, tuple[asyncio.TimerHandle, Callable[[], None]]] = {}
        self._held_key = 0

    def _fate(self, message: RobotMessage) -> Fate:
        if isinstance(message, Request) and not self.reachable(message.receiver):
            return Fate(dropped=True, reason="range")
        other = message.receiver if message.sender == self.robot else message.sender
        if other in self.cut:  # a nemesis's partition
            return Fate(dropped=True, reason="outage")
        return self.plan.fate(message.kind, message.sender, message.receiver, message.step,
                              self.distance(other, message.step))

    def _transmit(self, message: RobotMessage, size: int, copies: int) -> float:
        """Spend the energy of ``copies`` transmissions of ``message``; returns the airtime of one
        (realtime with a disk or log-distance radio; else 0)."""
        radio = self.plan.radio
        bits = message_bits(radio, size)
        spent = copies * transmit_energy(radio, bits, self.distance(message.receiver, message.step))
        self.energy_j[0] += spent
        self._step_energy.setdefault(message.step, ([], []))[0].append(spent)
        return airtime_s(radio, size) if self.realtime and radio.model != "ideal" else 0.0

    def _receive(self, message: RobotMessage, size: int, copies: int) -> None:
        spent = copies * receive_energy(self.plan.radio, message_bits(self.plan.radio, size))
        self.energy_j[1] += spent
        self._step_energy.setdefault(message.step, ([], []))[1].append(spent)

    def energy_through(self, step: int) -> tuple[float, float]:
        """The radio energy (transmit, receive; joules) of the robot's messages stamped with ``step``
        or earlier, each step's added in sorted order: the same bits whatever order its messages
        came in. In lockstep every message of a step before the robot's current one has been sent
        and received by the time it commands (a copy that comes later still counts, at the next
        call), so this is what a robot's command reports (:attr:`bus.messages.Command.energy_j`)."""
        for done in sorted(key for key in self._step_energy if key <= step):
            transmitted, received = self._step_energy.pop(done)
            self._settled_j[0] += sum(sorted(transmitted))
            self._settled_j[1] += sum(sorted(received))
        return self._settled_j[0], self._settled_j[1]

    def send(self, destination: str, message: Message) -> bool:
        """Publish ``message``; for a request, its fate applies. Returns False if it was dropped."""
        if not isinstance(message, (Request, Reply, Push)):
            self.participant.send(destination, message)
            return True
        fate = self._fate(message) if isinstance(message, Request) else DELIVERED
        published = int(published_copies(fate.dropped, fate.copies))
        self.counter.count_sent(published)
        self._settle(message, fate)
        payload = encode(message)
        if published and isinstance(message, Request):
            self._requests[message.nonce] = [message.step, message.receiver, published, len(payload), 0]
        elif isinstance(message, Push):
            self._pushes.append((message.step, (PUSH, message.receiver, 1, len(payload))))
        # every copy on the bus is on the air; a message dropped before publishing was still sent once
        airtime = self._transmit(message, len(payload), max(published, 1))
        if fate.dropped:
            return False
        for _ in range(fate.copies):
            if fate.delay_s or airtime:
                self._hold(fate.delay_s + airtime, destination, message, payload)
            else:
                self.participant.send(destination, message, payload)
        return True

    def _hold(self, delay_s: float, destination: str, message: Message, payload: bytes) -> None:
        """Publish a copy ``delay_s`` seconds from now (a delayed one), unless :meth:`release_held`
        publishes it first."""
        key = self._held_key = self._held_key + 1

        def publish() -> None:
            del self._held[key]
            self.participant.send(destination, message, payload)

        self._held[key] = (asyncio.get_running_loop().call_later(delay_s, publish), publish)

    def release_held(self) -> None:
        """Publish every delayed copy still held, now: the robot is leaving, and its books (what it
        sent) must hold every message it will ever put on the bus."""
        for timer, publish in list(self._held.values()):
            timer.cancel()
            publish()

    def receive(self, delivery: Delivery) -> tuple[list[Delivery], bool]:
        """``(deliveries for the robot now, lost)``; a reply's fate applies on arrival."""
        message = delivery.message
        if isinstance(message, (Request, Reply, Push)) and not delivery.released:
            self.counter.count_arrived()
            if isinstance(message, Reply):
                self._note_reply(message, delivery.size)
        if not isinstance(message, (Request, Reply, Push)) or delivery.released:
            if isinstance(message, (Request, Reply, Push)):
                self.counter.count_delivered(1)
                self._receive(message, delivery.size, 1)
            return [delivery], False
        fate = self._fate(message) if isinstance(message, (Reply, Push)) else DELIVERED
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
        self._receive(message, delivery.size, len(copies))
        return copies, False

    def _note_reply(self, reply: Reply, size: int) -> None:
        """Note the size of the first reply that came to an open request of this step."""
        request = self._requests.get(reply.nonce)
        if request is not None and request[1] == reply.sender and not request[4]:
            request[4] = size

    def take_traffic(self, step: int) -> list[RobotTraffic]:
        """The robot-to-robot messages the robot's ``step`` has put on the bus, as the robot counted
        them (:data:`bus.messages.RobotTraffic`): every request published, with the replies to it
        (one per copy the peer received; none when no reply came before now), and every push.
        Forgets them and those of earlier steps (a realtime robot may leave a step without
        commanding): the next step starts afresh."""
        rows: list[RobotTraffic] = []
        for sent_in, peer, copies, size, reply_size in self._requests.values():
            if sent_in == step:
                rows.append((REQUEST, peer, copies, size))
                if reply_size:
                    rows.append((REPLY, peer, copies, reply_size))
        rows += [row for sent_in, row in self._pushes if sent_in == step]
        self._requests, self._pushes = {}, []
        return rows

    def _settle(self, message: RobotMessage, fate: Fate) -> None:
        """Count what ``fate`` does to ``message`` and report each fault to the monitor."""
        self.counter.count_fate(fate)
        for what in fate.faults:
            notice = FaultNotice(SCHEMA, self.participant.keys.run, message.step, message.kind, message.sender,
                                 message.receiver, what, fate.reason or "", fate.delay_s)
            self.participant.send(MONITOR, notice)
