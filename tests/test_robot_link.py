"""The robot process's link between its protocol and the bus (agents/process.py), without a bus."""

from __future__ import annotations

import asyncio
import itertools

from ringtrack.agents.node import RobotNode
from ringtrack.agents.process import Deadline, RobotLink
from ringtrack.bus.inbox import Inbox
from ringtrack.bus.keys import Keys
from ringtrack.bus.messages import SCHEMA, Command, Message, Reply, Request, encode
from ringtrack.bus.participant import Delivery
from ringtrack.world.scenario import load_scenario
from ringtrack.world.state import WorldState

RUN = 0x52
ROBOT = 2


class Bus:
    """Stands in for robot 2's participant: keeps what it publishes, and its inbox."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.keys = Keys(RUN)
        self.name = f"r{ROBOT}"
        self.inbox: Inbox[object] = Inbox(loop)
        self.sent: list[tuple[str, Message]] = []

    def send(self, destination: str, message: Message, payload: bytes | None = None) -> int:
        self.sent.append((destination, message))
        return len(payload or encode(message))


def delivery(message: Message, source: str) -> Delivery:
    keys = Keys(RUN)
    route = keys.parse(keys.data(f"r{ROBOT}", source, message.kind))
    assert route is not None
    return Delivery(message, route, len(encode(message)))


def poll_at_step_one(bus: Bus) -> tuple[RobotNode, WorldState, RobotLink, list[Request]]:
    """Robot 2 of the constant strategy (it polls every step) with a reply timeout of 0.05 s, after
    the first measurement."""
    scenario = load_scenario("paper-stationary", strategy="constant")
    counter = itertools.count(1000)
    node = RobotNode(ROBOT, scenario, RUN, nonce=lambda: next(counter))
    world = WorldState(scenario, 0, RUN, 100)
    link = RobotLink(bus, node, reply_timeout=0.05)  # type: ignore[arg-type]
    link.deliver(delivery(world.measurement(ROBOT), "world"))
    requests = [message for _, message in bus.sent if isinstance(message, Request)]
    assert [request.receiver for request in requests] == [1, 3]
    return node, world, link, requests


def test_a_poll_left_unanswered_gets_its_reply_deadline_and_commands() -> None:
    async def scenario() -> None:
        bus = Bus(asyncio.get_running_loop())
        try:
            node, _, link, _ = poll_at_step_one(bus)
            await asyncio.sleep(0.15)  # past the deadline
            posted = bus.inbox.take()
            assert posted == [Deadline(1, "replies")]
            link.deadline(posted[0])
            assert isinstance(bus.sent[-1][1], Command) and node.awaiting == {}
        finally:
            bus.inbox.close()

    asyncio.run(scenario())


def test_a_polls_reply_deadline_is_cancelled_once_the_robot_leaves_its_step() -> None:
    """Every poll arms a reply deadline (in lockstep, seconds away). Once the next step's measurement
    came, the deadline could only be ignored, so it is cancelled: it never falls due to wake the
    robot (step 2's does, its replies never came)."""

    async def scenario() -> None:
        bus = Bus(asyncio.get_running_loop())
        try:
            _, world, link, requests = poll_at_step_one(bus)
            [(step, first_timer)] = link.deadlines
            assert step == 1 and not first_timer.cancelled()
            for request in requests:
                position = tuple(float(v) for v in world.positions[request.receiver])
                reply = Reply(SCHEMA, RUN, 1, request.receiver, ROBOT, request.nonce, position)
                link.deliver(delivery(reply, f"r{request.receiver}"))
            assert isinstance(bus.sent[-1][1], Command)
            world.advance()  # the team holds still: the next step is all this test needs
            link.deliver(delivery(world.measurement(ROBOT), "world"))  # step 2 polls too
            assert first_timer.cancelled() and [step for step, _ in link.deadlines] == [2]
            await asyncio.sleep(0.15)  # past both deadlines
            assert bus.inbox.take() == [Deadline(2, "replies")]
        finally:
            bus.inbox.close()

    asyncio.run(scenario())
