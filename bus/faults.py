"""Faults on robot-to-robot links: drops, outages (partitions), limited range, delay, duplication.

A :class:`FaultPlan` gives every robot-to-robot message a *fate* that depends only on the plan's seed,
on ``(kind, sender, receiver, step)`` and, with a lossy radio (:mod:`bus.radio`), on the link's
length at the start of the step, never on timing or on the order of arrival, so a lockstep run with
faults is reproducible and the engine computes exactly the same fates, for a whole batch of
messages at once (:meth:`FaultPlan.decide`; :meth:`FaultPlan.fate` is the one-message view).

Each poll's fates are settled in the polling robot's own process (:class:`bus.shim.LinkShim`): a
request's on the way out, a reply's on the way in; a push's (a belief a robot tells its neighbours
unasked) on the way in, in the receiver's process, so a push is always published once. A robot
therefore learns at once that an answer will not come (the explicit loss notice of a lockstep run)
and never waits for it. Links are undirected pairs of
robot ids; an outage takes a set of links down for steps ``first..last`` (inclusive).
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.bus.radio import IDEAL, Radio, message_loss

Reason = Literal["drop", "outage", "range", "gone", "radio"]
FAULT_COUNTERS = ("sent", "delivered", "dropped", "duplicated", "delayed", "published")
POLL_MESSAGES = 4  # a poll that meets no fault: a request to each ring neighbour and each one's reply
# Codes of :attr:`Fates.reason` (0: delivered); "range" and "gone" are decided by the callers.
REASONS: tuple[Reason | None, ...] = (None, "outage", "radio", "drop", "range")
KIND_CODES = {"request": 1, "reply": 2, "push": 4}
LINK_CODE = 3  # draws of a link (both directions, every kind): its shadowing
SALTS = {"drop": 1, "duplicate": 2, "jitter": 3, "radio": 4, "shadow": 5, "shadow-phase": 6}
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX = (np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def _mix64(z: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The SplitMix64 finaliser: a bijection of 64-bit words that scatters every input bit."""
    z = (z ^ (z >> np.uint64(30))) * _MIX[0]
    z = (z ^ (z >> np.uint64(27))) * _MIX[1]
    return z ^ (z >> np.uint64(31))


def keyed_uniform(seed: ArrayLike, salt: str, kind: ArrayLike, sender: ArrayLike, receiver: ArrayLike,
                  step: ArrayLike) -> NDArray[np.float64]:
    """Uniform numbers in [0, 1) keyed by the seed, the draw's ``salt`` and the message's identity
    (``kind`` a code of :data:`KIND_CODES`), broadcast over arrays: a counter-based hash (SplitMix64
    rounds over the seed, the salt and kind, the step, then the robot pair), so the engine draws a
    whole step's messages at once and a robot each of its own. Robot ids must be below 2^31."""
    with np.errstate(over="ignore"):
        word = _mix64(np.asarray(seed % 2**64 if isinstance(seed, int) else seed).astype(np.uint64) + _GOLDEN)
        word = _mix64(word ^ (np.asarray(SALTS[salt] << 8 | np.asarray(kind)).astype(np.uint64) + _GOLDEN))
        word = _mix64(word ^ (np.asarray(step).astype(np.uint64) + _GOLDEN))
        pair = np.asarray(sender, dtype=np.int64) << 32 | np.asarray(receiver, dtype=np.int64)
        word = _mix64(_mix64(word ^ (pair.astype(np.uint64) + _GOLDEN)))
    return (word >> np.uint64(11)).astype(np.float64) * 2.0**-53


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
        if not (self.dropped or self.copies > 1 or self.delay_s > 0):
            return ()
        counts = fate_counts(self.dropped, self.copies, self.delay_s)
        return tuple(what for what in FAULTS if counts[what])


FAULTS = ("dropped", "duplicated", "delayed")  # what a fate can do to a message


def fate_counts(dropped: ArrayLike, copies: ArrayLike, delay_s: ArrayLike,
                messages: ArrayLike = 1) -> dict[str, NDArray[np.int64]]:
    """What fates do to ``messages`` messages each (scalars or arrays, elementwise), counter by
    counter: a dropped message is ``dropped`` and nothing else; a kept one is ``delivered`` in its
    copies, ``duplicated`` by its copies beyond the first and ``delayed`` when its delay is positive.
    The one rule of :class:`FaultCounter` (a robot's fault layer, one message at a time) and of the
    engine (a step of a batch of teams at once)."""
    dropped = np.asarray(dropped, dtype=bool)
    kept, copies, messages = ~dropped, np.asarray(copies, dtype=np.int64), np.asarray(messages, dtype=np.int64)
    return {"dropped": messages * dropped, "delivered": messages * kept * copies,
            "duplicated": messages * kept * (copies - 1), "delayed": messages * kept * (np.asarray(delay_s) > 0)}


DELIVERED = Fate()


def published_copies(dropped: ArrayLike, copies: ArrayLike) -> NDArray[np.int64] | int:
    """Copies of requests put on the bus, given their fates (elementwise): every copy, none for a
    request dropped before sending (:class:`bus.shim.LinkShim` settles a request's fate on the way
    out and a reply's on the way in, after it was published). One fate's (``dropped`` a bool) is an int."""
    if isinstance(dropped, bool):
        return 0 if dropped else int(copies)
    return np.where(dropped, 0, np.asarray(copies, dtype=np.int64))


def request_traffic(request: Fate) -> int:
    """Robot-to-robot messages one request of a poll puts on the bus, given its fate: each copy
    (:func:`published_copies`) and the one reply each delivered copy is answered with. Every count of
    published robot-to-robot traffic (the engine's :func:`agents.engine.ring_traffic`, the monitor's
    step records and per-link rows, the fault layer's ``published``) follows from this."""
    return POLL_MESSAGES // 2 * int(published_copies(request.dropped, request.copies))


@dataclass(frozen=True)
class Fates:
    """The fates of a batch of messages (arrays of one shape): ``reason`` a code of :data:`REASONS`
    (0: delivered), the ``copies`` delivered and the ``delay_s`` of each."""

    reason: NDArray[np.int8]
    copies: NDArray[np.int64]
    delay_s: NDArray[np.float64]

    @property
    def dropped(self) -> NDArray[np.bool_]:
        return self.reason != 0

    def counts(self, messages: ArrayLike = 1) -> dict[str, NDArray[np.int64]]:
        """What these fates do to ``messages`` messages each (:func:`fate_counts`)."""
        return fate_counts(self.dropped, self.copies, self.delay_s, messages)


@dataclass(frozen=True)
class FaultPlan:
    """The faults of a run. ``default`` applies to every link, ``links`` overrides some."""

    seed: int = 0
    default: LinkRates = LinkRates()
    links: dict[frozenset[int], LinkRates] = field(default_factory=dict)
    outages: tuple[Outage, ...] = ()
    radio: Radio = IDEAL

    @cached_property
    def active(self) -> bool:
        rates = [self.default, *self.links.values()]
        lossy = self.radio.lossy or bool(self.outages)
        return lossy or any(r.drop or r.duplicate or r.delay_s or r.jitter_s for r in rates)

    def fate(self, kind: str, sender: int, receiver: int, step: int, distance: float | None = None) -> Fate:
        """The fate of the ``kind`` message ``sender -> receiver`` of ``step`` over a link of
        ``distance`` metres at the step's start (needed by a lossy radio only)."""
        if not self.active:  # a clean plan: no draws (a robot settles every message it sends)
            return DELIVERED
        fates = self.decide(kind, sender, receiver, step, 0.0 if distance is None else distance)
        reason, copies, delay = REASONS[int(fates.reason)], int(fates.copies), float(fates.delay_s)
        if reason is not None:
            return Fate(dropped=True, reason=reason)
        return Fate(copies=copies, delay_s=delay) if copies > 1 or delay else DELIVERED

    def decide(self, kind: str, sender: ArrayLike, receiver: ArrayLike, step: int, distance: ArrayLike = 0.0,
               seed: ArrayLike | None = None) -> Fates:
        """The fates of the ``kind`` messages ``sender -> receiver`` of ``step`` (arrays broadcast
        together, with ``distance`` in metres and, for a batch of runs, each message's plan
        ``seed``; default the plan's): lost in an outage, lost by the radio, dropped, else
        delivered once or twice after a delay. Each draw is its own keyed uniform; the link's
        shadowing is drawn once per link and step, whatever the direction or kind."""
        sender, receiver = np.asarray(sender, dtype=np.int64), np.asarray(receiver, dtype=np.int64)
        seed = self.seed if seed is None else np.asarray(seed)
        shape = np.broadcast_shapes(sender.shape, receiver.shape, np.shape(distance), np.shape(seed))
        code = KIND_CODES[kind]

        def draw(salt: str) -> NDArray[np.float64]:
            return np.broadcast_to(keyed_uniform(seed, salt, code, sender, receiver, step), shape)

        reason = np.zeros(shape, dtype=np.int8)
        for outage in self.outages:
            if outage.first <= step <= outage.last:
                for pair in outage.links:
                    a, b = sorted(pair)
                    covered = ((sender == a) & (receiver == b)) | ((sender == b) & (receiver == a))
                    reason[(reason == 0) & covered] = REASONS.index("outage")
        if self.radio.lossy:
            low, high = np.minimum(sender, receiver), np.maximum(sender, receiver)
            radius = np.sqrt(-2.0 * np.log1p(-keyed_uniform(seed, "shadow", LINK_CODE, low, high, step)))
            normal = radius * np.cos(2.0 * np.pi * keyed_uniform(seed, "shadow-phase", LINK_CODE, low, high, step))
            lost = draw("radio") < message_loss(self.radio, distance, self.radio.shadowing_db * normal)
            reason[(reason == 0) & lost] = REASONS.index("radio")
        drop, duplicate, delay, jitter = self._rate_arrays(sender, receiver, shape)
        if np.any(drop):
            reason[(reason == 0) & (draw("drop") < drop)] = REASONS.index("drop")
        copies = np.where(draw("duplicate") < duplicate, 2, 1) if np.any(duplicate) else np.ones(shape, np.int64)
        if np.any(jitter):
            delay = np.where(jitter > 0, np.maximum(0.0, delay + jitter * (2.0 * draw("jitter") - 1.0)), delay)
        delay = np.broadcast_to(delay, shape)
        return Fates(reason, copies.astype(np.int64), delay)

    def _rate_arrays(self, sender: NDArray[np.int64], receiver: NDArray[np.int64],
                     shape: tuple[int, ...]) -> list[NDArray[np.float64]]:
        """Drop and duplicate probabilities, delay and jitter (s) of each message's link (0-d arrays
        when no link has its own)."""
        defaults = (self.default.drop, self.default.duplicate, self.default.delay_s, self.default.jitter_s)
        if not self.links:
            return [np.asarray(value, dtype=float) for value in defaults]
        arrays = [np.full(shape, value, dtype=float) for value in defaults]
        for pair, rates in self.links.items():
            a, b = sorted(pair)
            on = np.broadcast_to(((sender == a) & (receiver == b)) | ((sender == b) & (receiver == a)), shape)
            for array, value in zip(arrays, (rates.drop, rates.duplicate, rates.delay_s, rates.jitter_s), strict=True):
                array[on] = value
        return arrays


NO_FAULTS = FaultPlan()


@dataclass
class FaultCounter:
    """Robot-to-robot messages ``sent`` (each message the protocol sends, once), ``delivered`` to a
    robot (every copy), ``dropped``, ``duplicated`` (extra copies), ``delayed``, and ``published``
    (copies put on the bus: what the monitor sees); so that ``sent + duplicated == delivered +
    dropped`` once every message has arrived. A request dropped before sending is sent but never
    published, a reply duplicated on arrival published once: ``published`` is the sum of
    :func:`request_traffic` over the requests. Counted by :func:`fate_counts`, the rule the engine
    applies to a whole step at once. ``arrived`` counts the copies taken off the bus by the robot's
    fault layer: what a team published and never took off is lost in transit (:func:`team_faults`)."""

    counts: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)

    def count_sent(self, published: int) -> None:
        """One message sent, put on the bus ``published`` times (0: dropped before sending)."""
        self.counts["sent"] += 1
        self.counts["published"] += published

    def count_fate(self, fate: Fate) -> None:
        """What ``fate`` did to one message: dropped (and why), extra copies, delayed."""
        if fate is DELIVERED or fate == DELIVERED:
            return  # nothing to count: the common case, spared the arrays of fate_counts
        counts = fate_counts(fate.dropped, fate.copies, fate.delay_s)
        for what in FAULTS:
            self.counts[what] += int(counts[what])
        if fate.reason:
            self.reasons[fate.reason] += 1

    def count_delivered(self, copies: int) -> None:
        self.counts["delivered"] += copies

    def count_arrived(self) -> None:
        """One published copy taken off the bus (before its fate on arrival, if any, applies)."""
        self.counts["arrived"] += 1

    def table(self) -> dict[str, int]:
        return {name: self.counts[name] for name in (*FAULT_COUNTERS, "arrived")}


def team_faults(tables: list[dict[str, int]]) -> dict[str, int]:
    """A team's fault counts from its robots' :meth:`FaultCounter.table` s: the sums of
    :data:`FAULT_COUNTERS`, and ``lost``, the copies published that no robot took off the bus (in
    flight to a robot frozen past the liveliness lease, whose link Zenoh then dropped; answered by a
    woken robot before its links re-formed; arriving after their receiver ended), counted among the
    ``dropped``: so ``sent + duplicated == delivered + dropped`` holds for every message published.
    A robot that never reported (killed) leaves its own sends uncounted and ``lost`` at most an
    estimate (never below 0)."""
    totals: Counter[str] = sum((Counter(table) for table in tables), Counter())
    lost = max(0, totals["published"] - totals["arrived"])
    return {**{name: totals[name] for name in FAULT_COUNTERS}, "dropped": totals["dropped"] + lost, "lost": lost}


# A supervisor's nemesis cuts robot links at run time: it writes the links cut now to this file in
# the run folder, {"cut": [[a, b], ...]}, and tells the robots at their ends (SIGUSR1) to read it.
PARTITION_FILE = "partition.json"


def cut_peers(folder: Path, robot: int) -> frozenset[int]:
    """The robots whose links to ``robot`` the run folder's :data:`PARTITION_FILE` says are cut now
    (none when there is no such file, or it cannot be read)."""
    try:
        cut = json.loads((folder / PARTITION_FILE).read_text())["cut"]
        return frozenset(int(b if a == robot else a) for a, b in cut if robot in (a, b))
    except (OSError, ValueError, KeyError, TypeError):
        return frozenset()
