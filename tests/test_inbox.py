"""The inboxes of one event loop (bus.inbox): pushes from any thread, one doorbell per loop."""

from __future__ import annotations

import asyncio
import os
import threading

from ringtrack.bus.inbox import Doorbell, Inbox

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
