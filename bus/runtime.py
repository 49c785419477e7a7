"""Running one participant in an asyncio process: session lifecycle, signals, presence.

Every role of a run (world, robot, fusion centre, monitor) lives the same life, which :func:`perform`
runs for the :class:`Role` it is given: join the run, subscribe, announce itself alive, gather until
everyone it needs is up, announce itself ready, run its own loop to an exit code, send its final
statistics to the monitor, and linger until its last messages have had time to arrive.

``joined`` opens the session and always undeclares and closes it on the way out, so a process
never hangs on exit; its :class:`Interrupts` post an :class:`Interrupt` to the participant's inbox
on SIGINT or SIGTERM (and, with ``exit_with_parent``, when standard input reaches end of file
because the parent died). One process may host several participants sharing one ``Interrupts``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass, field
from typing import Literal

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.bus.keys import MONITOR, WORLD, Keys
from ringtrack.bus.lives import life_label
from ringtrack.bus.messages import Stats
from ringtrack.bus.participant import Event, Interrupt, Participant, Presence, peak_rss_kib


class Interrupts:
    """Delivers SIGINT, SIGTERM and, with ``exit_with_parent``, the end of the parent (standard input,
    a pipe from it, reaching end of file) as :class:`Interrupt` events to every participant of this
    process: a process may host several robots, each its own participant."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, exit_with_parent: bool = False, parent_grace_s: float = 10.0) -> None:
        self.exit_with_parent = exit_with_parent
        self.parent_grace_s = parent_grace_s  # s: how long the process may take to stop once its parent exited
        self.participants: list[Participant] = []
        self.loop: asyncio.AbstractEventLoop | None = None

    def add(self, participant: Participant) -> None:
        if self.loop is None:
            self._install(asyncio.get_running_loop())
        self.participants.append(participant)

    def remove(self, participant: Participant) -> None:
        self.participants.remove(participant)
        if not self.participants and self.loop is not None:
            for number in self.SIGNALS:
                self.loop.remove_signal_handler(number)
            self.loop = None

    def fire(self, reason: str) -> None:
        for participant in list(self.participants):
            participant.inbox.push(Interrupt(reason))

    def _install(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        for number in self.SIGNALS:
            loop.add_signal_handler(number, self.fire, signal.Signals(number).name)
        if self.exit_with_parent:
            threading.Thread(target=self._wait_for_parent, name="parent-watch", daemon=True).start()
            self.exit_with_parent = False  # one watcher per process

    def _wait_for_parent(self) -> None:
        # Raw reads: a daemon thread blocked in a buffered reader aborts interpreter shutdown.
        with contextlib.suppress(OSError):
            while os.read(sys.stdin.fileno(), 4096):
                pass
        loop = self.loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self.fire, "parent exited")
        # A process whose loop cannot act (its thread stuck in a call that never returns, as a Zenoh
        # declaration that deadlocks) must still not outlive its parent: this daemon thread ends it.
        time.sleep(self.parent_grace_s)
        with contextlib.suppress(OSError):
            os.write(sys.stderr.fileno(), f"ringtrack: the parent exited and this process did not stop within "
                                          f"{self.parent_grace_s:g} s; exiting\n".encode())
        os._exit(STOPPED)


@contextlib.asynccontextmanager
async def joined(
    config: BusConfig, keys: Keys, name: str, robots: int, interrupts: Interrupts
) -> AsyncIterator[Participant]:
    """Open a session and yield the :class:`Participant` ``name`` of run ``keys.run``; signals reach
    it through ``interrupts``, shared by the participants of one process."""
    loop = asyncio.get_running_loop()
    session = open_session(config, name)
    participant = Participant(session, keys, name, robots, loop)
    interrupts.add(participant)
    try:
        yield participant
    finally:
        write_final_counts(participant)
        interrupts.remove(participant)
        participant.close()
        session.close()


COUNTS_FOLDER_ENV = "RINGTRACK_COUNTS_FOLDER"  # set by a supervisor (spawn) to its run folder


def write_final_counts(participant: Participant) -> None:
    """With ``RINGTRACK_COUNTS_FOLDER`` set, write what ``participant`` sent (its traffic rows) and
    its peak memory (KiB) to ``<folder>/<name>.sent.json`` (``<name>.life<n>.sent.json`` for a
    robot's life n > 1, :mod:`bus.lives`) as it leaves: the senders' own counts,
    which a supervisor reads when the monitor that collects them was lost. Best effort: a process
    killed by SIGKILL writes nothing, and a file that cannot be written is skipped (none is left
    half-written)."""
    folder = os.environ.get(COUNTS_FOLDER_ENV)
    if not folder:
        return
    name = life_label(participant.name, participant.life)
    path = os.path.join(folder, f"{name}.sent.json")
    try:
        with open(f"{path}.partial", "w") as file:
            json.dump({"name": name, "sent": participant.counter.sent_table(),
                       "rss_kib": peak_rss_kib()}, file)
        os.replace(f"{path}.partial", path)
    except OSError:  # a full disk: leave no partial file behind
        with contextlib.suppress(OSError):
            os.unlink(f"{path}.partial")


# A token's withdrawal travels ahead of the data its owner sent before leaving (liveliness
# declarations have their own priority): wait this long for, e.g., the world's End; never more than
# half the liveliness lease, so that a lost world or monitor is noticed within one lease of its loss.
DEPARTURE_GRACE_S = 3.0


def departure_grace_s(lease_ms: int) -> float:
    """Seconds a departed participant's last messages are waited for: ``DEPARTURE_GRACE_S``, or half
    the liveliness lease ``lease_ms`` (milliseconds) when that is shorter."""
    return min(DEPARTURE_GRACE_S, lease_ms / 2000)


@dataclass
class Roster:
    """Which participants hold an ``alive`` and a ``ready`` token right now, and since when
    (``time.monotonic()``) each departed participant has been gone."""

    alive: set[str] = field(default_factory=set)
    ready: set[str] = field(default_factory=set)
    departed: dict[str, float] = field(default_factory=dict)
    grace_s: float = DEPARTURE_GRACE_S  # seconds: how long a departed participant's last messages are awaited

    def update(self, presence: Presence) -> None:
        names = self.alive if presence.kind == "alive" else self.ready
        (names.add if presence.up else names.discard)(presence.name)
        if presence.kind == "alive":
            if presence.up:
                self.departed.pop(presence.name, None)
            else:
                self.departed.setdefault(presence.name, time.monotonic())

    def gone_for_good(self, name: str) -> bool:
        """``name`` left more than ``grace_s`` seconds ago (its last messages had time to arrive)."""
        since = self.departed.get(name)
        return since is not None and time.monotonic() - since > self.grace_s


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
    return await participant.events(None if watched in roster.alive else 0.5)


LINGER_S = 3.0


async def linger(participant: Participant, roster: Roster, names: set[str], limit_s: float = LINGER_S) -> None:
    """Stay up until none of ``names`` is alive, at most ``limit_s`` seconds.

    A session closed right after its last publication can lose it in flight (seen with Zenoh
    clients), and a participant vanishing before its last message arrives looks like a crash. So the
    world waits for its robots to leave on its End, and every sender waits for the monitor, which
    leaves once it holds everyone's final statistics.
    """
    try:
        await asyncio.wait_for(gather_until(participant, roster, lambda: not names & roster.alive), limit_s)
    except TimeoutError:
        pass


STOPPED = 130  # the exit code of a participant stopped by a signal (or its parent's end)

Main = Callable[[Participant, Roster, list[Event]], Awaitable[int]]


def final_stats(participant: Participant, code: int) -> Stats | None:
    """The default last word of a role: everything it sent, received and rejected."""
    return participant.stats(final=True)


@dataclass
class Role:
    """One participant's part in a run, as :func:`perform` lives it.

    ``name`` joins the run listening on ``listen`` (or, for the monitor, collecting ``collect``) key
    expressions; once every participant of ``needed`` holds its ``start_on`` token (the world waits
    for "ready", everyone else for "alive") and after announcing itself ready (``announces_ready``),
    it runs ``main(participant, roster, events seen meanwhile)`` to an exit code, then sends
    ``stats(participant, code)`` to the monitor (None: nothing) and stays up while any of
    ``linger_for(code)`` is alive (see :func:`linger`). ``before_alive`` is awaited just before it
    declares its ``alive`` token (a robot checks that its id is free), ``on_joined`` runs once it is alive (the
    world announces its endpoints there), ``on_gathering(roster)`` at every presence change while it
    waits for the others (the monitor's start-up frame shows who is up).
    """

    name: str
    needed: set[str]
    main: Main
    listen: tuple[str, ...] = ()
    collect: tuple[str, ...] = ()
    start_on: Literal["alive", "ready"] = "alive"
    announces_ready: bool = True
    before_alive: Callable[[Participant], Awaitable[None]] | None = None
    on_joined: Callable[[Participant], None] | None = None
    on_gathering: Callable[[Roster], None] | None = None
    stats: Callable[[Participant, int], Stats | None] = final_stats
    linger_for: Callable[[int], set[str]] = lambda code: set()


async def perform(role: Role, bus: BusConfig, keys: Keys, robots: int, interrupts: Interrupts) -> int:
    """Live ``role`` in run ``keys.run`` of ``robots`` robots; returns its exit code (``STOPPED``
    when interrupted before it started)."""
    async with joined(bus, keys, role.name, robots, interrupts) as participant:
        for key_expr in role.listen:
            participant.listen(key_expr)
        for key_expr in role.collect:
            participant.collect(key_expr)
        participant.watch("alive")
        if role.start_on == "ready":
            participant.watch("ready")
        if role.before_alive is not None:
            await role.before_alive(participant)
        participant.announce("alive")
        if role.on_joined is not None:
            role.on_joined(participant)
        roster = Roster(grace_s=departure_grace_s(bus.lease_ms))
        tokens = roster.alive if role.start_on == "alive" else roster.ready
        def everyone_there() -> bool:
            if role.on_gathering is not None:
                role.on_gathering(roster)
            return role.needed <= tokens

        started, held = await gather_until(participant, roster, everyone_there)
        if not started:
            return STOPPED
        if role.announces_ready:
            participant.announce("ready")
        code = await role.main(participant, roster, held)
        stats = role.stats(participant, code)
        if stats is not None:
            participant.send(MONITOR, stats)
        lingering = role.linger_for(code)
        if lingering:
            await linger(participant, roster, lingering)
        return code
