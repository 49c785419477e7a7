"""A robot's fault layer counts what its step put on the bus (bus/shim.py), and the inbox that wakes
its event loop keeps one timer per deadline (bus/inbox.py)."""

from __future__ import annotations

import asyncio
import threading

from ringtrack.bus.faults import FaultPlan, LinkRates
from ringtrack.bus.inbox import Inbox
from ringtrack.bus.keys import Keys
from ringtrack.bus.messages import NONCE_BASE, ROBOT_TRAFFIC_KINDS, SCHEMA, Message, Push, Reply, Request, encode
from ringtrack.bus.participant import Delivery
from ringtrack.bus.shim import LinkShim

RUN = NONCE_BASE + 7
REQUEST, REPLY, PUSH = (ROBOT_TRAFFIC_KINDS.index(kind) for kind in ("request", "reply", "push"))


class Published:
    """Stands in for a participant: keeps what the shim publishes."""

    def __init__(self) -> None:
        self.keys = Keys(RUN)
        self.sent: list[tuple[str, Message, bytes | None]] = []

    def send(self, destination: str, message: Message, payload: bytes | None = None) -> int:
        self.sent.append((destination, message, payload))
        return len(payload or encode(message))


def shim_of(plan: FaultPlan, robot: int = 1) -> tuple[LinkShim, Published]:
    published = Published()
    return LinkShim(published, plan, robot, lambda _: True, lambda _robot, _step: 2.0), published  # type: ignore[arg-type]


def delivery(message: Reply) -> Delivery:
    payload = encode(message)
    return Delivery(message, Keys(RUN).parse(Keys(RUN).data("r1", f"r{message.sender}", "reply")), len(payload))


def test_a_step_counts_its_requests_the_replies_to_them_and_its_pushes() -> None:
    shim, published = shim_of(FaultPlan())
    requests = [Request(SCHEMA, RUN, 40, 1, neighbour, NONCE_BASE + neighbour) for neighbour in (0, 2)]
    for request in requests:
        assert shim.send(f"r{request.receiver}", request)
    push = Push(SCHEMA, RUN, 40, 1, 2, (1.0, 2.0), (1.0, 0.0, 1.0))
    shim.send("r2", push)
    # Each message is encoded once: the payload published is the one counted.
    assert [payload for _, _, payload in published.sent] == [encode(m) for m in (*requests, push)]
    # Only robot 2 answers before the step commands; a reply with a wrong nonce is not an answer.
    answer = Reply(SCHEMA, RUN, 40, 2, 1, NONCE_BASE + 2, (3.25, 4.5))
    shim.receive(delivery(Reply(SCHEMA, RUN, 40, 0, 1, NONCE_BASE + 99, (1.0, 1.0))))
    shim.receive(delivery(answer))
    assert shim.take_traffic(40) == [
        (REQUEST, 0, 1, len(encode(requests[0]))),
        (REQUEST, 2, 1, len(encode(requests[1]))),
        (REPLY, 2, 1, len(encode(answer))),
        (PUSH, 2, 1, len(encode(push))),
    ]
    assert shim.take_traffic(40) == []  # the next step starts afresh
    # A step left without a command (realtime) is not reported with the next one.
    shim.send("r2", Request(SCHEMA, RUN, 41, 1, 2, NONCE_BASE + 3))
    assert shim.take_traffic(42) == []


def test_a_duplicated_request_is_answered_twice_and_a_dropped_one_not_at_all() -> None:
    shim, published = shim_of(FaultPlan(default=LinkRates(duplicate=1.0)))
    request = Request(SCHEMA, RUN, 7, 1, 2, NONCE_BASE + 5)
    shim.send("r2", request)
    assert len(published.sent) - 1 == 2  # two copies, and a fault notice to the monitor
    answer = Reply(SCHEMA, RUN, 7, 2, 1, NONCE_BASE + 5, (0.5, 0.5))
    shim.receive(delivery(answer))
    size = len(encode(answer))
    assert shim.take_traffic(7) == [(REQUEST, 2, 2, len(encode(request))), (REPLY, 2, 2, size)]

    shim, published = shim_of(FaultPlan(default=LinkRates(drop=1.0)))
    assert not shim.send("r2", request)
    assert shim.take_traffic(7) == []  # nothing went on the bus


def test_the_inbox_waits_for_items_or_its_deadline_with_one_timer() -> None:
    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        inbox: Inbox[int] = Inbox(loop)
        until = loop.time() + 0.05
        assert await inbox.batch(until=until) == []  # nothing came before the deadline
        assert loop.time() >= until - 0.01
        timer = inbox._timer
        assert await inbox.batch(until=until) == []  # the same deadline: at once, the same timer
        assert inbox._timer is timer
        threading.Timer(0.02, inbox.push, (7,)).start()  # pushed from another thread
        assert await inbox.batch(until=loop.time() + 30.0) == [7]
        assert inbox._timer is not timer
        inbox.push(8)
        inbox.push(9)
        assert await inbox.batch() == [8, 9]  # everything queued, in one batch
        inbox.close()

    asyncio.run(scenario())
