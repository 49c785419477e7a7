"""One named participant of a run (the world, the monitor, robot i) on a Zenoh session.

It encodes, counts and publishes outgoing messages, and turns incoming samples and liveliness
changes into validated messages and :class:`Presence` events on an asyncio loop. Every payload that
fails validation is dropped and counted by reason, never raised.
"""

from __future__ import annotations

import asyncio
import ctypes
import logging
import resource
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import zenoh

from ringtrack.bus.counting import TrafficCounter
from ringtrack.bus.inbox import Inbox
from ringtrack.bus.keys import Keys, Route
from ringtrack.bus.messages import SCHEMA, AnyMessage, Message, Rejected, Stats, decode, encode
from ringtrack.bus.outbox import Outbox

log = logging.getLogger(__name__)

PresenceKind = Literal["alive", "ready"]
# A message stamped this many steps past its receiver's current step is no genuine one (a real
# participant lags by seconds at most; a forger picks 2^64 - 1): dropped at the door (far_ahead).
WINDOW_STEPS = 4096


def far_ahead(message: Message, step: int) -> str | None:
    """``"window"`` (a :data:`bus.messages.REJECT_REASONS` reason) when ``message`` is stamped more
    than :data:`WINDOW_STEPS` steps past ``step``, the receiver's current step (0: it knows none
    yet, and takes every step); else None. A role's :attr:`Participant.window`."""
    stamped = getattr(message, "step", None)
    return "window" if step > 0 and isinstance(stamped, int) and stamped > step + WINDOW_STEPS else None
CONTROL_KINDS = frozenset({"measurement", "command", "tick", "end"})


@dataclass(frozen=True)
class Presence:
    """A liveliness change: participant ``name`` is ``up`` (or gone) as ``kind``."""

    kind: PresenceKind
    name: str
    up: bool


@dataclass(slots=True)
class Delivery:
    """A validated message with the route its key named and its payload size in bytes; ``released``
    once a fault layer has settled its fate (a delayed or duplicated copy). One is made for every
    message received, so it is not frozen (a frozen dataclass sets each field through
    ``object.__setattr__``: 3.5 x the cost); nothing changes one after it is made."""

    message: AnyMessage
    route: Route
    size: int
    released: bool = False
    life: int = 0  # the sender's life (bus.lives); 0: a participant with one life


@dataclass(frozen=True)
class Interrupt:
    """The process was asked to stop (a signal, or the parent that started it went away)."""

    reason: str


class Posted:
    """Base of the events a process posts to its own inbox (a timer that fell due): they pass through
    :meth:`Participant.accept` unchanged, between the bus's own events."""


Event = Delivery | Presence | Interrupt | Posted
# A sample as a Zenoh callback hands it over: key expression, payload, the sender's life (0: none).
Raw = tuple[str, bytes, int]
LIFE_BYTES = 4  # a life number on the wire (a sample's attachment): unsigned, little-endian


def life_attachment(life: int) -> bytes:
    """The attachment that stamps a sample with its sender's ``life`` (:mod:`bus.lives`)."""
    return life.to_bytes(LIFE_BYTES, "little")


def attached_life(attachment: zenoh.ZBytes | None) -> int:
    """The sender's life a sample's attachment carries; 0 for a sample without one (the world, the
    monitor and the fusion centre have one life each) or with one of another shape."""
    if attachment is None:
        return 0
    raw = attachment.to_bytes()
    return int.from_bytes(raw, "little") if len(raw) == LIFE_BYTES else 0


def raw(sample: zenoh.Sample) -> Raw:
    """What :meth:`Participant.accept` takes of ``sample``."""
    return str(sample.key_expr), sample.payload.to_bytes(), attached_life(sample.attachment)


def peak_rss_kib() -> int:
    """Peak resident memory (KiB) of this process since it started its program: ``VmHWM``. (The
    ``ru_maxrss`` of ``getrusage`` also counts the parent's memory before ``exec``, so a robot
    started by a large process would report that process's size.)"""
    try:
        status = Path("/proc/self/status").read_text()
        return int(next(line.split()[1] for line in status.splitlines() if line.startswith("VmHWM:")))
    except (OSError, StopIteration, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


_callback_thread = threading.local()


def _keep_thread_state() -> None:
    """Keep the Python thread state of the Zenoh thread running this callback for the life of the
    process. Zenoh's threads are not Python's: each callback takes the interpreter lock with
    ``PyGILState_Ensure`` and gives it back with ``PyGILState_Release``, which, on a thread with no
    state of its own, creates a thread state (and maps its 16 KiB frame stack) and deletes it again
    (unmapping it, which interrupts the other cores to flush their TLBs) for every sample. One
    unmatched ``PyGILState_Ensure`` per thread keeps the state, so later callbacks only take the lock
    (measured: 12-15 us less CPU per received message, about a sixth)."""
    if not getattr(_callback_thread, "kept", False):
        ctypes.pythonapi.PyGILState_Ensure()
        _callback_thread.kept = True


def _direct(callback: Callable[[zenoh.Sample], None]) -> zenoh.handlers.Callback:
    """Run ``callback`` on Zenoh's network thread rather than on a Python thread of its own: our
    callbacks only append to a deque, and the saved thread hop halves the CPU of a round trip
    (measured 227 -> 128 us per process). The thread keeps its Python state (:func:`_keep_thread_state`)."""

    def on_network_thread(sample: zenoh.Sample) -> None:
        _keep_thread_state()
        callback(sample)

    return zenoh.handlers.Callback(on_network_thread, indirect=False)


class Participant:
    """Send and receive the messages of one participant of run ``keys.run`` with ``robots`` robots."""

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        name: str,
        robots: int,
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.session = session
        self.keys = keys
        self.name = name
        self.robots = robots
        self.counter = TrafficCounter()
        self.inbox: Inbox[Raw | Event] = Inbox(loop)
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._outbox = Outbox.of(loop)
        self._open = True
        self._entities: list[object] = []
        self._channels: list[zenoh.Handler[zenoh.Sample]] = []
        self.callback_failures = 0
        # The role's check at the door: a decoded message it names a reason for ("window": a step far
        # ahead of its own) is dropped and counted as rejected, never as traffic.
        self.window: Callable[[Message], str | None] | None = None
        # Fenced lives (bus.lives): this participant's own life (0: none, it is no robot) and the
        # newest life seen or granted of every sender; a message of an older one is "superseded".
        self.life = 0
        self._attachment: bytes | None = None
        self.lives: dict[str, int] = {}
        self.life_history: dict[str, list[int]] = {}  # every life each sender was seen to take up, in order
        self.fenced = TrafficCounter()  # received (as counted here) = messages of superseded lives, per link

    # ------------------------------------------------------------------ receiving
    def listen(self, key_expr: str) -> None:
        """Receive data samples on ``key_expr``, waking the loop for each burst (latency first)."""
        self._entities.append(self.session.declare_subscriber(key_expr, _direct(self._on_sample)))

    def collect(self, key_expr: str, capacity: int = 1 << 16) -> None:
        """Receive data samples on ``key_expr`` into a Zenoh FIFO channel that :meth:`drain` empties
        (throughput first: no Python code and no wake-up per sample; for the monitor). A full
        channel pushes back on the senders rather than dropping."""
        subscriber = self.session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(capacity))
        self._entities.append(subscriber)
        self._channels.append(subscriber.handler)

    def drain(self) -> list[Event]:
        """Take everything waiting in the channels of :meth:`collect` and in the inbox, validated."""
        batch: list[Raw | Event] = []
        for channel in self._channels:
            while (sample := channel.try_recv()) is not None:
                batch.append(raw(sample))
        while self.inbox.pending():
            batch.extend(self.inbox.take())
        return self.accept(batch)

    def watch(self, kind: PresenceKind) -> None:
        """Receive :class:`Presence` events for every ``kind`` token of the run, current ones first."""
        key_expr = self.keys.alive() if kind == "alive" else self.keys.ready()
        self._entities.append(
            self.session.liveliness().declare_subscriber(
                key_expr, _direct(lambda sample: self._on_token(kind, sample)), history=True
            )
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            self.inbox.push(raw(sample))
        except Exception:  # pragma: no cover - a failing callback must never go silent
            self.callback_failures += 1
            log.exception("sample callback failed")

    def _on_token(self, kind: PresenceKind, sample: zenoh.Sample) -> None:
        try:
            name = str(sample.key_expr).rsplit("/", 1)[-1]
            self.inbox.push(Presence(kind, name, sample.kind == zenoh.SampleKind.PUT))
        except Exception:  # pragma: no cover
            self.callback_failures += 1
            log.exception("liveliness callback failed")

    async def events(self, timeout: float | None = None, until: float | None = None) -> list[Event]:
        """Wait for and return the next batch of validated messages and presence changes (after
        ``timeout`` seconds, or once the loop's clock reached ``until``; None: never, perhaps an
        empty one)."""
        batch = await self.inbox.batch(timeout, until)
        return self.accept(batch)

    def accept(self, batch: list[Raw | Event]) -> list[Event]:
        """Decode, validate and count raw samples; rejected payloads are counted and dropped."""
        accepted: list[Event] = []
        for item in batch:
            if not isinstance(item, tuple):
                accepted.append(item)
                continue
            key, payload, life = item
            route = self.keys.parse(key)
            try:
                message = decode(payload, route, self.keys.run, self.robots)
            except Rejected as rejection:
                self.counter.count_rejected(rejection.reason)
                continue
            assert route is not None
            if self.window is not None and (reason := self.window(message)) is not None:
                self.counter.count_rejected(reason)
                continue
            newest = self.lives.get(route.source, 0)
            if life < newest and not (life and message.kind == "stats"):  # an older life's books still count
                if not life:  # no life at all: no robot sent it (each stamps its life)
                    self.counter.count_rejected("unstamped")
                    continue
                self.counter.count_rejected("superseded")  # an older life: a replaced process
                self.fenced.count_received((message.kind, route.source, route.destination), len(payload))
                continue
            if life > newest or route.source not in self.lives:
                self.lives[route.source] = life
                self.life_history.setdefault(route.source, []).append(life)
            self.counter.count_received((message.kind, route.source, route.destination), len(payload))
            accepted.append(Delivery(message, route, len(payload), life=life))
        return accepted

    # ------------------------------------------------------------------ sending
    def live_as(self, life: int) -> None:
        """Stamp every message from now on with ``life`` (granted by the world, :mod:`bus.lives`)."""
        self.life = life
        self._attachment = life_attachment(life)

    def announce(self, kind: PresenceKind) -> None:
        """Declare this participant's ``kind`` liveliness token (withdrawn when the session closes)."""
        key = self.keys.alive(self.name) if kind == "alive" else self.keys.ready(self.name)
        self._entities.append(self.session.liveliness().declare_token(key))

    def send(self, destination: str, message: Message, payload: bytes | None = None) -> int:
        """Publish ``message`` to ``destination`` (a participant name or "all"); returns its bytes.
        ``payload`` is ``message`` encoded, when the caller has it already."""
        key = self.keys.data(destination, self.name, message.kind)
        if payload is None:
            payload = encode(message)
        publisher = self._publishers.get(key)
        if publisher is None:
            publisher = self.session.declare_publisher(
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                priority=zenoh.Priority.INTERACTIVE_HIGH if message.kind in CONTROL_KINDS else zenoh.Priority.DATA,
            )
            self._publishers[key] = publisher
        self._outbox.put(publisher, payload, self._attachment)
        self.counter.count_sent((message.kind, self.name, destination), len(payload))
        return len(payload)

    def stats(self, final: bool, faults: dict[str, int] | None = None, notes: dict[str, int] | None = None,
              energy_j: tuple[float, float] | None = None) -> Stats:
        """What this participant has sent, received and rejected so far, what its fault layer did
        (``faults``), protocol counters (``notes``) and a robot's radio energy (transmit, receive; J)."""
        return Stats(
            SCHEMA,
            self.keys.run,
            name=self.name,
            final=final,
            sent=self.counter.sent_table(),
            received=self.counter.received_table(),
            rejected=self.counter.rejected_table(),
            rss_kib=peak_rss_kib(),
            faults=faults or {},
            notes=notes or {},
            energy_j=energy_j,
        )

    def close(self) -> None:
        """Put what the loop's outbox holds, then undeclare every entity (call before the event loop
        ends; the session is closed by its owner)."""
        if self._open:
            self._open = False
            self._outbox.release()
        for entity in [*self._publishers.values(), *reversed(self._entities)]:
            try:
                entity.undeclare()  # type: ignore[attr-defined]
            except Exception:  # pragma: no cover - the session may already be closed
                pass
        self._publishers.clear()
        self._entities.clear()
        self._channels.clear()
        self.inbox.close()
