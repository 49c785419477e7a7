"""The inboxes and the outbox of one event loop (bus.inbox, bus.outbox): pushes from any thread and one
doorbell per loop; puts held to the end of the loop iteration when the loop hosts several participants."""

from __future__ import annotations

import asyncio
import os
import threading

from ringtrack.bus.inbox import Doorbell, Inbox
from ringtrack.bus.outbox import Outbox

INBOXES = 16  # the robots of a packed process


def test_a_burst_into_every_inbox_of_a_loop_rings_its_doorbell_once_and_wakes_each() -> None:
    async def run() -> tuple[int, list[list[int]], bool]:
        loop = asyncio.get_running_loop()
        inboxes: list[Inbox[int]] = [Inbox(loop) for _ in range(INBOXES)]
        doorbell = Doorbell.of(loop)
        doorbell.release()  # only looked at
        pusher = threading.Thread(target=lambda: [inbox.push(index) for index, inbox in enumerate(inboxes)])
        pusher.start()
        pusher.join()  # a burst from Zenoh's thread while the loop was busy
        rings = os.eventfd_read(doorbell._eventfd)  # writes since the last read: the eventfd's counter
        os.eventfd_write(doorbell._eventfd, rings)  # put them back for the loop's reader
        batches = await asyncio.wait_for(asyncio.gather(*(inbox.batch() for inbox in inboxes)), 10.0)
        for inbox in inboxes:
            inbox.close()
        return rings, batches, loop in Doorbell._of_loop

    rings, batches, still_rung = asyncio.run(run())
    assert rings == 1
    assert batches == [[index] for index in range(INBOXES)]
    assert not still_rung  # the last inbox closed took the doorbell off the loop


def test_a_push_while_the_loop_takes_a_batch_wakes_it_again() -> None:
    async def run() -> list[list[int]]:
        loop = asyncio.get_running_loop()
        inbox: Inbox[int] = Inbox(loop)
        taken = []
        for item in range(3):
            threading.Thread(target=inbox.push, args=(item,)).start()
            taken.append(await asyncio.wait_for(inbox.batch(), 10.0))
        inbox.close()
        return taken

    assert asyncio.run(run()) == [[0], [1], [2]]


class Publisher:
    """A Zenoh publisher that records what it puts in ``puts``, shared by several."""

    def __init__(self, name: str, puts: list[tuple[str, bytes]]) -> None:
        self.name, self.puts = name, puts

    def put(self, payload: bytes, attachment: bytes | None = None) -> None:
        self.puts.append((self.name, payload))


def test_a_loop_with_one_participant_puts_at_once() -> None:
    async def run() -> list[tuple[str, bytes]]:
        outbox = Outbox.of(asyncio.get_running_loop())
        puts: list[tuple[str, bytes]] = []
        outbox.put(Publisher("r0", puts), b"now")  # type: ignore[arg-type]
        seen = list(puts)
        outbox.release()
        return seen

    assert asyncio.run(run()) == [("r0", b"now")]


def test_a_loop_with_several_participants_puts_once_the_iteration_is_over_in_order() -> None:
    async def run() -> tuple[list, list, list]:
        loop = asyncio.get_running_loop()
        outboxes = [Outbox.of(loop) for _ in range(INBOXES)]  # one per robot of a packed process
        assert all(outbox is outboxes[0] for outbox in outboxes)
        puts: list[tuple[str, bytes]] = []
        publishers = [Publisher(f"r{robot}", puts) for robot in range(2)]
        for index in range(3):
            outboxes[index].put(publishers[index % 2], b"%d" % index)  # type: ignore[arg-type]
        during = list(puts)
        await asyncio.sleep(0)  # the iteration ends: the held puts go, in order
        after = list(puts)
        outboxes[0].put(publishers[0], b"last")  # type: ignore[arg-type]
        for outbox in outboxes:
            outbox.release()  # the first release puts what is held
        return during, after, puts

    during, after, puts = asyncio.run(run())
    assert during == []
    assert after == [("r0", b"0"), ("r1", b"1"), ("r0", b"2")]
    assert puts == [*after, ("r0", b"last")]


def test_each_loop_has_its_own_doorbell_and_outbox_until_its_last_user_releases_it() -> None:
    loops = [asyncio.new_event_loop() for _ in range(2)]
    try:
        first, second = (Outbox.of(loop) for loop in loops)
        assert first is not second and Outbox.of(loops[0]) is first and first.users == 2
        assert [first.release(), first.release()] == [False, True]
        assert Outbox.of(loops[0]) is not first  # forgotten after its last user: a new one
        doorbells = [Doorbell.of(loop) for loop in loops]
        assert doorbells[0] is not doorbells[1] and all(doorbell.release() for doorbell in doorbells)
    finally:
        for loop in loops:
            loop.close()
