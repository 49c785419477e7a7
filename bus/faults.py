"""Faults on robot-to-robot links: drops, outages (partitions), limited range, delay, duplication.

A :class:`FaultPlan` gives every robot-to-robot message a *fate* that depends only on the plan's seed
and on ``(kind, sender, receiver, step)``, never on timing or on the order of arrival, so a lockstep
run with faults is reproducible and the engine can compute exactly the same fates.

Each poll's fates are settled in the polling robot's own process (:class:`bus.shim.LinkShim`): a
request's on the way out, a reply's on the way in. A robot therefore learns at once that an answer will not come
(the explicit loss notice of a lockstep run) and never waits for it. Links are undirected pairs of
robot ids; an outage takes a set of links down for steps ``first..last`` (inclusive).
"""

from __future__ import annotations

import hashlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Literal

Reason = Literal["drop", "outage", "range", "gone"]
FAULT_COUNTERS = ("sent", "delivered", "dropped", "duplicated", "delayed", "published")
POLL_MESSAGES = 4  # a poll that meets no fault: a request to each ring neighbour and each one's reply


def link(a: int, b: int) -> frozenset[int]:
    return frozenset((a, b))


@dataclass(frozen=True)
class LinkRates:
    """Per-message probabilities and the delay of one link (seconds of wall time)."""

    drop: float = 0.0
    duplicate: float = 0.0
    delay_s: float = 0.0
    jitter_s: float = 0.0


@dataclass(frozen=True)
class Outage:
    """Links down for steps ``first..last`` (a partition when they cut the ring)."""

    links: frozenset[frozenset[int]]
    first: int
    last: int

    def covers(self, pair: frozenset[int], step: int) -> bool:
        return self.first <= step <= self.last and pair in self.links


@dataclass(frozen=True)
class Fate:
    """What happens to one message: ``dropped`` (and why), or delivered ``copies`` times after ``delay_s``."""

    dropped: bool = False
    reason: Reason | None = None
    copies: int = 1
    delay_s: float = 0.0

    @property
    def faults(self) -> tuple[str, ...]:
        """What the fault layer did to the message: ``("dropped",)``, or any of "duplicated" and
        "delayed" (each reported to the monitor as a ``FaultNotice`` and logged as an event)."""
        if self.dropped:
            return ("dropped",)
        return ("duplicated",) * (self.copies > 1) + ("delayed",) * (self.delay_s > 0)


DELIVERED = Fate()


def request_traffic(request: Fate) -> int:
    """Robot-to-robot messages one request of a poll puts on the bus, given its fate: each copy and
    the one reply each delivered copy is answered with; 0 for a request dropped before sending
    (:class:`bus.shim.LinkShim` settles a request's fate on the way out and a reply's on the way in,
    after it was published). Every count of published robot-to-robot traffic (the engine's, the
    monitor's step records and per-link rows, the fault layer's ``published``) follows from this."""
    return 0 if request.dropped else 2 * request.copies


@dataclass(frozen=True)
class FaultPlan:
    """The faults of a run. ``default`` applies to every link, ``links`` overrides some."""

    seed: int = 0
    default: LinkRates = LinkRates()
    links: dict[frozenset[int], LinkRates] = field(default_factory=dict)
    outages: tuple[Outage, ...] = ()

    @property
    def active(self) -> bool:
        rates = [self.default, *self.links.values()]
        return bool(self.outages) or any(r.drop or r.duplicate or r.delay_s or r.jitter_s for r in rates)

    def rates(self, a: int, b: int) -> LinkRates:
        return self.links.get(link(a, b), self.default)

    def fate(self, kind: str, sender: int, receiver: int, step: int) -> Fate:
        """The fate of the ``kind`` message ``sender -> receiver`` of ``step``."""
        pair = link(sender, receiver)
        if any(outage.covers(pair, step) for outage in self.outages):
            return Fate(dropped=True, reason="outage")
        rates = self.rates(sender, receiver)
        if rates.drop and self._uniform("drop", kind, sender, receiver, step) < rates.drop:
            return Fate(dropped=True, reason="drop")
        copies = 2 if rates.duplicate and self._uniform("duplicate", kind, sender, receiver, step) < rates.duplicate else 1
        delay = rates.delay_s
        if rates.jitter_s:
            delay = max(0.0, delay + rates.jitter_s * (2.0 * self._uniform("jitter", kind, sender, receiver, step) - 1.0))
        return Fate(copies=copies, delay_s=delay) if copies > 1 or delay else DELIVERED

    def _uniform(self, salt: str, kind: str, sender: int, receiver: int, step: int) -> float:
        """A uniform number in [0, 1) from the plan's seed and the message's identity."""
        key = f"{self.seed}:{salt}:{kind}:{sender}:{receiver}:{step}".encode()
        return int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "big") / 2.0**64


NO_FAULTS = FaultPlan()


@dataclass
class FaultCounter:
    """Robot-to-robot messages ``sent`` (each message the protocol sends, once), ``delivered`` to a
    robot (every copy), ``dropped``, ``duplicated`` (extra copies), ``delayed``, and ``published``
    (copies put on the bus: what the monitor sees); so that ``sent + duplicated == delivered +
    dropped`` once every message has arrived. A request dropped before sending is sent but never
    published, a reply duplicated on arrival published once: ``published`` is the sum of
    :func:`request_traffic` over the requests. The engine counts with this class as the robots'
    fault layers do."""

    counts: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)

    def count_sent(self, published: int) -> None:
        """One message sent, put on the bus ``published`` times (0: dropped before sending)."""
        self.counts["sent"] += 1
        self.counts["published"] += published

    def count_fate(self, fate: Fate) -> None:
        """What ``fate`` did to one message: dropped (and why), extra copies, delayed."""
        for what in fate.faults:
            self.counts[what] += fate.copies - 1 if what == "duplicated" else 1
        if fate.reason:
            self.reasons[fate.reason] += 1

    def count_delivered(self, copies: int) -> None:
        self.counts["delivered"] += copies

    def table(self) -> dict[str, int]:
        return {name: self.counts[name] for name in FAULT_COUNTERS}
