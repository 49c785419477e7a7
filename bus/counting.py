"""Counting messages and bytes by kind and link, on the sending and on the receiving side."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

from ringtrack.bus.keys import robot_index
from ringtrack.bus.messages import KINDS, REJECT_REASONS, Traffic

Link = tuple[str, str, str]  # (kind, source, destination)


def category_of(kind: str) -> str:
    """"robot" (robot-to-robot traffic the strategies try to save), "world", "estimation" (ranges
    to and estimates from the fusion centre) or "monitoring"."""
    message_type = KINDS.get(kind)
    return message_type.category if message_type else "unknown"


@dataclass
class TrafficCounter:
    """Messages and payload bytes per ``(kind, source, destination)``, sent and received, plus
    received payloads that were rejected, by reason."""

    sent_messages: Counter[Link] = field(default_factory=Counter)
    sent_bytes: Counter[Link] = field(default_factory=Counter)
    received_messages: Counter[Link] = field(default_factory=Counter)
    received_bytes: Counter[Link] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)

    def count_sent(self, link: Link, size: int) -> None:
        self.sent_messages[link] += 1
        self.sent_bytes[link] += size

    def count_received(self, link: Link, size: int) -> None:
        self.received_messages[link] += 1
        self.received_bytes[link] += size

    def count_rejected(self, reason: str) -> None:
        self.rejected[reason] += 1

    @staticmethod
    def table(messages: Counter[Link], sizes: Counter[Link]) -> list[Traffic]:
        """Rows ``(kind, source, destination, messages, bytes)`` sorted by link."""
        return [(*link, messages[link], sizes[link]) for link in sorted(messages)]

    def sent_table(self) -> list[Traffic]:
        return self.table(self.sent_messages, self.sent_bytes)

    def received_table(self) -> list[Traffic]:
        return self.table(self.received_messages, self.received_bytes)

    def rejected_table(self) -> dict[str, int]:
        return {reason: self.rejected[reason] for reason in REJECT_REASONS if self.rejected[reason]}


Totals = dict[str, int]  # {"messages": m, "bytes": b}
Key = TypeVar("Key", bound=Hashable)


def summed(rows: Iterable[Sequence[Any]], key: Callable[[Sequence[Any]], Key]) -> dict[Key, Totals]:
    """``{key(row): {"messages": m, "bytes": b}}`` summed over traffic rows ``(kind, source,
    destination, messages, bytes)``, in order of first appearance (bytes None, as engine logs have
    them, count 0)."""
    totals: dict[Key, Totals] = {}
    for row in rows:
        entry = totals.setdefault(key(row), {"messages": 0, "bytes": 0})
        entry["messages"] += row[3]
        entry["bytes"] += row[4] or 0
    return totals


def totals_by_category(rows: Iterable[Sequence[Any]]) -> dict[str, Totals]:
    return summed(rows, lambda row: category_of(row[0]))


def totals_by_kind(rows: Iterable[Sequence[Any]]) -> dict[str, Totals]:
    return summed(rows, lambda row: row[0])


def per_link(rows: Iterable[Sequence[Any]], categories: tuple[str, ...]) -> dict[Link, Totals]:
    """Totals per (kind, source, destination) of the rows of ``categories``."""
    return summed((row for row in rows if category_of(row[0]) in categories), lambda row: tuple(row[:3]))


def robot_link_totals(rows: Iterable[Sequence[Any]]) -> dict[tuple[str, str], Totals]:
    """Robot-to-robot totals per (sender, receiver), requests and replies together, ordered by
    sender then receiver index."""
    links = summed((row for row in rows if category_of(row[0]) == "robot"), lambda row: (row[1], row[2]))
    return {pair: links[pair] for pair in sorted(links, key=lambda pair: (robot_index(pair[0]) or 0,
                                                                          robot_index(pair[1]) or 0))}


@dataclass(frozen=True)
class Books:
    """How a run's books close, link by link (``(kind, source, destination)``, categories compared).

    ``said`` is what the senders, every life of each, counted as sent; ``seen`` what the monitor saw
    (taken in, or dropped at its door as a replaced life's). A link balances when the two agree; a
    shortfall on a link one of whose ends was cut off during the run (``cut_off``: it left, froze
    past the lease or was replaced) is ``in_flight``: messages counted as sent that were still
    queued in, or on their way to, a process when its links closed. On a link from a sender one of
    whose lives left no books (``silent``: killed before it could send them), the messages seen
    beyond those counted are that life's, as the wire audit saw them (``unbooked``). A monitor that
    resumed the books of one that went away cannot have seen what was sent in between: its other
    shortfalls are ``unobserved``. Anything else is ``unexplained``: (said, seen) messages."""

    in_flight: dict[Link, int]
    unexplained: dict[Link, tuple[int, int]]
    unbooked: dict[Link, int] = field(default_factory=dict)
    unobserved: dict[Link, int] = field(default_factory=dict)

    @property
    def balanced(self) -> bool:
        return not self.unexplained

    def lines(self) -> list[str]:
        """One line per link that did not simply agree, naming what happened."""
        lines = [f"{kind} {source} > {destination}: {count} in flight when the link closed (a process was cut off)"
                 for (kind, source, destination), count in sorted(self.in_flight.items())]
        lines += [f"{kind} {source} > {destination}: {count} of a life of {source} that left no books (killed), "
                  "as the wire audit saw them" for (kind, source, destination), count in sorted(self.unbooked.items())]
        lines += [f"{kind} {source} > {destination}: {count} sent while the monitor was away, unseen by the monitor "
                  "that resumed its books (unobserved)"
                  for (kind, source, destination), count in sorted(self.unobserved.items())]
        lines += [f"{kind} {source} > {destination}: {said} sent, {seen} seen (unexplained)"
                  for (kind, source, destination), (said, seen) in sorted(self.unexplained.items())]
        return lines


def close_books(said_rows: Iterable[Sequence[Any]], seen_rows: Iterable[Sequence[Any]], cut_off: set[str],
                categories: tuple[str, ...], silent: frozenset[str] = frozenset(), unobserved: bool = False) -> Books:
    """Compare, on every link of ``categories``, the messages the senders counted (``said_rows``)
    with those the monitor saw (``seen_rows``), shortfalls on links touching ``cut_off`` (participant
    names) being in flight, other shortfalls unobserved when the monitor ``unobserved`` part of the
    run (it resumed the books of one that went away), and excesses on links from ``silent`` senders
    (a life of theirs left no books) unbooked (:class:`Books`). Bytes follow messages: a link whose
    message counts agree but whose bytes differ is unexplained too, unless its sender is ``silent``
    (what a life without books sent is known by the count the wire audit saw, not by its bytes)."""
    said, seen = per_link(said_rows, categories), per_link(seen_rows, categories)
    none = {"messages": 0, "bytes": 0}
    in_flight: dict[Link, int] = {}
    unexplained: dict[Link, tuple[int, int]] = {}
    unbooked: dict[Link, int] = {}
    unseen: dict[Link, int] = {}
    for link in sorted(said.keys() | seen.keys()):
        sent, got = said.get(link, none), seen.get(link, none)
        if sent == got or (link[1] in silent and sent["messages"] == got["messages"]):
            continue  # (the bytes of a life that left no books are not known: its messages are compared)
        short = sent["messages"] - got["messages"]
        if short > 0 and (link[1] in cut_off or link[2] in cut_off):
            in_flight[link] = short
        elif short > 0 and unobserved:
            unseen[link] = short
        elif short < 0 and link[1] in silent:
            unbooked[link] = -short
        else:
            unexplained[link] = (sent["messages"], got["messages"])
    return Books(in_flight, unexplained, unbooked, unseen)
