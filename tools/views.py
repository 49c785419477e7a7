"""What the monitor shows while a team runs, and its end-of-run report.

On a terminal the live dashboard (:mod:`tools.dashboard`), refreshed a few times per second by the
monitor and never per message; without one, a plain summary line every few seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from types import TracebackType

from rich.console import Console
from rich.live import Live
from rich.table import Table

from bus.counting import category_of
from bus.keys import robot_index
from tools.dashboard import Dashboard, TeamModel
from tools.monitor import MonitorReport

LINE_PERIOD_S = 2.0


class LiveView:
    """The monitor's display of a :class:`~tools.dashboard.TeamModel`: a rich Live dashboard redrawn
    on :meth:`refresh` (the caller decides how often, never per message), or without a dashboard a
    plain summary line every ``LINE_PERIOD_S`` seconds and at the end."""

    def __init__(self, console: Console, model: TeamModel, dashboard: bool) -> None:
        self.console = console
        self.model = model
        self.live = Live(Dashboard(model), console=console, auto_refresh=False) if dashboard else None
        self.last_line = 0.0

    def __enter__(self) -> "LiveView":
        if self.live is not None:
            self.live.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.live is not None:
            self.live.stop()

    def refresh(self, final: bool = False) -> None:
        if self.live is not None:
            self.live.refresh()
            return
        now = time.monotonic()
        if final or now - self.last_line >= LINE_PERIOD_S:
            self.console.print(self.model.summary_line(), highlight=False, soft_wrap=True)
            self.last_line = now


def per_robot_table(rows: list) -> Table:
    """Robot-to-robot messages and bytes each robot sent and received, and its world traffic."""
    robots = sorted({name for _, source, destination, _, _ in rows for name in (source, destination)
                     if robot_index(name) is not None}, key=robot_index)
    table = Table(title="per robot (messages / bytes)")
    for column in ("robot", "robot-to-robot sent", "robot-to-robot received", "from world", "to world"):
        table.add_column(column, justify="right")
    for name in robots:
        table.add_row(
            name,
            _sum(rows, lambda kind, source, _: category_of(kind) == "robot" and source == name),
            _sum(rows, lambda kind, _, destination: category_of(kind) == "robot" and destination == name),
            _sum(rows, lambda _, source, destination: source == "world" and destination == name),
            _sum(rows, lambda _, source, destination: source == name and destination == "world"),
        )
    return table


def _sum(rows: list, match: Callable[[str, str, str], bool]) -> str:
    """``"messages / bytes"`` over the traffic rows whose (kind, source, destination) match."""
    selected = [(count, size) for kind, source, destination, count, size in rows if match(kind, source, destination)]
    return f"{sum(count for count, _ in selected)} / {sum(size for _, size in selected)}"


def print_report(console: Console, report: MonitorReport) -> None:
    """Traffic by category as the monitor saw it and as the senders counted it."""
    table = Table(title="traffic (payload bytes)")
    for column in ("category", "messages seen", "bytes seen", "messages sent", "bytes sent", "bytes/message"):
        table.add_column(column, justify="right")
    mine, theirs = report.monitor_totals(), report.sender_totals()
    for category in ("robot", "world", "monitoring"):
        seen = mine.get(category, {"messages": 0, "bytes": 0})
        sent = theirs.get(category, {"messages": 0, "bytes": 0})
        per_message = f"{seen['bytes'] / seen['messages']:.1f}" if seen["messages"] else "-"
        table.add_row(category, str(seen["messages"]), str(seen["bytes"]), str(sent["messages"]),
                      str(sent["bytes"]), per_message)
    console.print(table)
    console.print(per_robot_table(report.received))
    verdict = "equal" if report.consistent() else "DIFFERENT"
    rejected = ", ".join(f"{reason} {count}" for reason, count in report.rejected.items()) or "none"
    ending = f"{report.end.reason} after {report.end.step} steps" if report.end else "no end record"
    console.print(f"run: {ending}; monitor vs senders: {verdict}; rejected: {rejected}; late: {report.late}",
                  highlight=False)
