"""Opening Zenoh sessions from a small configuration.

Embedded default: peer mode, listening on a free loopback port, multicast scouting off, gossip on,
so a team on one machine needs nothing installed or started beyond this package. Across hosts,
give ``listen``/``connect`` endpoints (``tcp/<ip>:<port>``) and optionally router mode.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Protocol

import zenoh

LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"
MAX_MESSAGE_BYTES = 4 << 20  # a team of a thousand robots' largest message (statistics) is 1 MiB
RECONNECT = {"period_init_ms": 200, "period_max_ms": 1000, "period_increase_factor": 2}
LEASE_S = 10.0  # Zenoh's default link lease: a frozen peer is seen gone after about as long
ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/(\[[0-9a-fA-F:.]+\]|[^/:\s]+):\d{1,5}$")

Mode = Literal["peer", "router", "client"]


class Secured(Protocol):
    """What a secure participant brings to its bus (:class:`bus.security.Security`, which needs the
    cryptography library and is made only by secure roles): its Zenoh settings and its checks."""

    def settings(self, name: str, mode: str) -> dict[str, object]:
        """Zenoh settings (``path: value``) of participant ``name`` in ``mode``."""
        ...

    def check(self, name: str) -> None:
        """Raise a :class:`BusError` unless ``name`` may join with this team's certificates."""
        ...

    def probe(self, name: str, endpoint: str) -> None:
        """Raise a :class:`BusError` unless whatever answers at ``endpoint`` is of this team."""
        ...


class BusError(ValueError):
    """The bus cannot be configured or reached; the message is one line naming the setting and fix."""


@dataclass(frozen=True)
class BusConfig:
    """How a process joins the bus.

    ``listen``/``connect`` are Zenoh endpoints such as ``tcp/127.0.0.1:7447``; port 0 picks a free
    port. ``lease_ms`` bounds how long a frozen peer still looks alive (liveliness; ``--lease``).
    """

    mode: Mode = "peer"
    listen: tuple[str, ...] = (LOOPBACK_ANY_PORT,)
    connect: tuple[str, ...] = ()
    lease_ms: int = round(LEASE_S * 1000)
    admin_space: bool = False  # needed to read back the locators a session bound (see listening_locators)
    extra: dict[str, object] = field(default_factory=dict)  # further "path": value JSON5 settings
    security: Secured | None = None  # --secure: mutual TLS and access control (bus.security)

    def __post_init__(self) -> None:
        for flag, endpoints in (("--listen", self.listen), ("--connect", self.connect)):
            for endpoint in endpoints:
                if not ENDPOINT.match(endpoint):
                    raise BusError(f"{flag} {endpoint!r} is not an endpoint; write it like tcp/127.0.0.1:7447")
                address = endpoint.partition("/")[2]
                if self.security is not None and not endpoint.startswith("tls/"):
                    raise BusError(f"{flag} {endpoint}: a --secure participant speaks only TLS; write tls/{address}")
                if self.security is None and endpoint.startswith("tls/"):
                    raise BusError(f"{flag} {endpoint}: TLS needs the team's certificates; add --secure DIR")
        if self.mode not in ("peer", "router", "client"):
            raise BusError(f"--mode {self.mode!r}: use peer, router or client")
        if self.mode == "client" and not self.connect:
            raise BusError("--mode client needs --connect ENDPOINT of a router or peer")

    def to_zenoh(self, name: str | None = None) -> zenoh.Config:
        """The Zenoh configuration of participant ``name`` (needed with ``security``: it picks the
        key and certificate)."""
        settings: dict[str, object] = {
            "mode": self.mode,
            "listen/endpoints": [] if self.mode == "client" else list(self.listen),
            "connect/endpoints": list(self.connect),
            "scouting/multicast/enabled": False,
            "transport/link/tx/lease": self.lease_ms,
            # A process woken after a freeze past the lease finds its links closed: it tries its
            # --connect endpoints again soon (from 0.2 s, at most every second), to learn within a
            # lease whether a newer life replaced it (bus.lives).
            "connect/retry": RECONNECT,
            # Zenoh drops, at the link, a message larger than any a team sends (a flood of 10 MiB
            # payloads never reaches a process's memory; the link stays up).
            "transport/link/rx/max_message_size": MAX_MESSAGE_BYTES,
            "adminspace/enabled": self.admin_space,
            # No shared memory: Zenoh would copy every payload of 3 kB or more (a digest, a large
            # team's statistics) into a 16 MiB pool mapped by sender and receiver alike.
            "transport/shared_memory/enabled": False,
            **self.extra,
        }
        if self.security is not None:
            if name is None:
                raise BusError("a secure session needs the participant's name")
            settings.update(self.security.settings(name, self.mode))
        config = zenoh.Config()
        for path, value in settings.items():
            config.insert_json5(path, json.dumps(value))
        return config


# One small Tokio runtime per process instead of one worker pool per runtime: a team runs many
# processes on few cores, where idle worker threads cost more than they give (measured: CPU per
# message round trip 160 us -> 90 us). An explicit ZENOH_RUNTIME in the environment wins. Zenoh reads
# it when a process opens its first session, so a process's first session decides its runtime.
COMPACT_RUNTIME = (
    "(app: (worker_threads: 1), acc: (handover: app), rx: (handover: app), tx: (handover: app), net: (handover: app))"
)
# A router forwards the others' messages from its receiving tasks. On one thread, a forward that waits
# for room in a full transmit queue (congestion control "block") holds the only thread that would
# empty that queue: the router stalls until Zenoh closes the link (after 5 s) and what was queued is
# lost. Seen at the end of a 256-robot run, when every robot's final statistics go through the world
# to the monitor at once. So a router's transmit tasks keep a thread of their own.
ROUTER_RUNTIME = "(app: (worker_threads: 1), acc: (handover: app), rx: (handover: app), net: (handover: app))"


def zenoh_runtime(mode: Mode) -> str:
    """The ``ZENOH_RUNTIME`` setting of a process whose session runs in ``mode``."""
    return ROUTER_RUNTIME if mode == "router" else COMPACT_RUNTIME


@contextlib.contextmanager
def network_threads_yield() -> Iterator[None]:
    """Threads started in this block (Zenoh's runtime, which the first session of a process starts)
    run as ``SCHED_BATCH``: a thread woken by a put or by a packet then never preempts the thread
    that is running on its core, it runs once that thread blocks or on a core that is free. Under
    the normal policy every put and every packet woke Zenoh's thread straight onto the core of the
    Python thread that was busy with its step, which then stood still until the send was done (a
    put took 90-100 us of wall time for 12-15 us of CPU) and the two traded the interpreter lock.
    A new thread inherits its creator's policy, so this thread takes the policy for the block and
    gives it back; where the policy cannot be set (not Linux, or refused), nothing changes."""
    previous: tuple[int, os.sched_param] | None = None
    if hasattr(os, "SCHED_BATCH"):
        try:
            previous = os.sched_getscheduler(0), os.sched_getparam(0)
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        except OSError:
            previous = None
    try:
        yield
    finally:
        if previous is not None:
            os.sched_setscheduler(0, *previous)


def open_session(config: BusConfig, name: str | None = None) -> zenoh.Session:
    """Open a Zenoh session for participant ``name``; close it with ``with`` or ``session.close()``
    in ``finally``. A secure participant first checks its certificate and that whatever answers at
    each ``connect`` endpoint is a secure participant of its team (else a one-line error). Zenoh's
    threads run as ``SCHED_BATCH`` (:func:`network_threads_yield`)."""
    if os.environ.get("ZENOH_RUNTIME") in (None, COMPACT_RUNTIME, ROUTER_RUNTIME):  # not the user's own
        os.environ["ZENOH_RUNTIME"] = zenoh_runtime(config.mode)
    if config.security is not None and name is not None:
        config.security.check(name)
        for endpoint in config.connect:
            config.security.probe(name, endpoint)
    try:
        with network_threads_yield():
            return zenoh.open(config.to_zenoh(name))
    except zenoh.ZError as error:
        raise BusError(f"cannot open the Zenoh session ({error}); check --listen/--connect") from None


def listening_locators(session: zenoh.Session) -> list[str]:
    """The endpoints this session actually listens on (ports resolved), read from its admin space.

    Needs ``BusConfig(admin_space=True)``.
    """
    for reply in session.get(f"@/{session.zid()}/*", timeout=2.0):
        if reply.ok is not None and str(reply.ok.key_expr).rsplit("/", 1)[-1] in ("peer", "router"):
            return list(json.loads(reply.ok.payload.to_bytes()).get("locators", []))
    raise BusError("cannot read the listening endpoints from the admin space; give --listen with a fixed port")


def announce_endpoints(session: zenoh.Session, path: Path) -> None:
    """Write ``{"endpoints": [...]}``, the endpoints ``session`` listens on, to ``path`` atomically, so
    a process started with port 0 can be found (needs ``BusConfig(admin_space=True)``)."""
    temporary = path.with_suffix(".tmp")
    temporary.write_text(json.dumps({"endpoints": listening_locators(session)}))
    temporary.replace(path)


def announced_endpoints(path: Path) -> list[str] | None:
    """The endpoints :func:`announce_endpoints` wrote to ``path``, or None while it has not."""
    try:
        return list(json.loads(path.read_text())["endpoints"])
    except FileNotFoundError:
        return None
