"""Handing samples from Zenoh's callback threads to an asyncio event loop.

Zenoh-Python has no asyncio API and calls callbacks on its own threads, where calling Zenoh again
is unsafe. The callback only appends to a deque and wakes the loop when no wake-up is pending
(one ``call_soon_threadsafe`` per burst rather than per sample); the loop drains whole batches.
"""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Generic, TypeVar

Item = TypeVar("Item")


class Inbox(Generic[Item]):
    """A many-producer (any thread), single-consumer (the loop) queue."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._items: deque[Item] = deque()
        self._ready = asyncio.Event()
        self._wake_pending = False

    def push(self, item: Item) -> None:
        """Add an item; safe from any thread, a no-op once the loop is closed."""
        self._items.append(item)
        if not self._wake_pending and not self._loop.is_closed():
            self._wake_pending = True
            try:
                self._loop.call_soon_threadsafe(self._wake)
            except RuntimeError:  # the loop closed between the check and the call
                pass

    def _wake(self) -> None:
        self._wake_pending = False
        self._ready.set()

    def pending(self) -> int:
        return len(self._items)

    async def batch(self) -> list[Item]:
        """Wait until at least one item is queued, then take everything queued."""
        while not self._items:
            self._ready.clear()
            if self._items:
                break
            await self._ready.wait()
        return self.take()

    def take(self) -> list[Item]:
        """Take everything queued now, without waiting."""
        items = []
        while self._items:
            items.append(self._items.popleft())
        return items
