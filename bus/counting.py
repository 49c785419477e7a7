"""Counting messages and bytes by kind and link, on the sending and on the receiving side."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from bus.messages import KINDS, REJECT_REASONS, Traffic

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


def totals_by_category(rows: list[Traffic]) -> dict[str, dict[str, int]]:
    """``{category: {"messages": m, "bytes": b}}`` summed over traffic rows."""
    totals: dict[str, dict[str, int]] = {}
    for kind, _source, _destination, messages, size in rows:
        entry = totals.setdefault(category_of(kind), {"messages": 0, "bytes": 0})
        entry["messages"] += messages
        entry["bytes"] += size
    return totals


def totals_by_kind(rows: list[Traffic]) -> dict[str, dict[str, int]]:
    """``{kind: {"messages": m, "bytes": b}}`` summed over traffic rows."""
    totals: dict[str, dict[str, int]] = {}
    for kind, _source, _destination, messages, size in rows:
        entry = totals.setdefault(kind, {"messages": 0, "bytes": 0})
        entry["messages"] += messages
        entry["bytes"] += size
    return totals
