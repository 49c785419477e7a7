"""Running one participant in an asyncio process: session lifecycle, signals, presence.

``joined`` opens the session, installs SIGINT/SIGTERM handlers that post an :class:`Interrupt` to
the participant's inbox (and, with ``exit_with_parent``, posts one when standard input reaches end
of file because the parent died), and always undeclares and closes on the way out, so a process
never hangs on exit.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field

from bus.config import BusConfig, open_session
from bus.keys import WORLD, Keys
from bus.participant import Event, Interrupt, Participant, Presence


@contextlib.asynccontextmanager
async def joined(
    config: BusConfig, keys: Keys, name: str, robots: int, exit_with_parent: bool = False
) -> AsyncIterator[Participant]:
    """Open a session and yield the :class:`Participant` ``name`` of run ``keys.run``."""
    loop = asyncio.get_running_loop()
    session = open_session(config)
    participant = Participant(session, keys, name, robots, loop)
    signals = (signal.SIGINT, signal.SIGTERM)
    for number in signals:
        loop.add_signal_handler(number, participant.inbox.push, Interrupt(signal.Signals(number).name))
    if exit_with_parent:
        _watch_parent(participant)
    try:
        yield participant
    finally:
        for number in signals:
            loop.remove_signal_handler(number)
        participant.close()
        session.close()


def _watch_parent(participant: Participant) -> None:
    """Post an Interrupt once standard input (a pipe from the parent) reaches end of file."""

    def wait_for_eof() -> None:
        # Raw reads: a daemon thread blocked in a buffered reader aborts interpreter shutdown.
        with contextlib.suppress(OSError):
            while os.read(sys.stdin.fileno(), 4096):
                pass
        participant.inbox.push(Interrupt("parent exited"))

    threading.Thread(target=wait_for_eof, name="parent-watch", daemon=True).start()


# A token's withdrawal travels ahead of the data its owner sent before leaving (liveliness
# declarations have their own priority): wait this long for, e.g., the world's End.
DEPARTURE_GRACE_S = 3.0


@dataclass
class Roster:
    """Which participants hold an ``alive`` and a ``ready`` token right now, and since when
    (``time.monotonic()``) each departed participant has been gone."""

    alive: set[str] = field(default_factory=set)
    ready: set[str] = field(default_factory=set)
    departed: dict[str, float] = field(default_factory=dict)

    def update(self, presence: Presence) -> None:
        names = self.alive if presence.kind == "alive" else self.ready
        (names.add if presence.up else names.discard)(presence.name)
        if presence.kind == "alive":
            if presence.up:
                self.departed.pop(presence.name, None)
            else:
                self.departed.setdefault(presence.name, time.monotonic())

    def gone_for_good(self, name: str) -> bool:
        """``name`` left more than ``DEPARTURE_GRACE_S`` ago (its last messages had time to arrive)."""
        since = self.departed.get(name)
        return since is not None and time.monotonic() - since > DEPARTURE_GRACE_S


async def gather_until(
    participant: Participant, roster: Roster, done: Callable[[], bool]
) -> tuple[bool, list[Event]]:
    """Track presence until ``done()``; returns ``(True, other events seen meanwhile)``, or
    ``(False, ...)`` when interrupted first."""
    held: list[Event] = []
    while not done():
        for event in await participant.events():
            if isinstance(event, Presence):
                roster.update(event)
            elif isinstance(event, Interrupt):
                return False, held
            else:
                held.append(event)
    return True, held


async def next_events(participant: Participant, roster: Roster, watched: str = WORLD) -> list[Event]:
    """The next batch of events; once ``watched`` has gone, wake at least every half second so the
    caller can give up when it is gone for good (``Roster.gone_for_good``)."""
    if watched in roster.alive:
        return await participant.events()
    try:
        return await asyncio.wait_for(participant.events(), 0.5)
    except TimeoutError:
        return []
