"""What the monitor shows while a team runs, and its end-of-run report.

On a terminal a rich progress bar (refreshed a few times per second by the monitor, never per
message); without one, a plain summary line every few seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from types import TracebackType

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from bus.counting import category_of, totals_by_category
from bus.keys import robot_index
from tools.monitor import MonitorReport, MonitorState
from world.scenario import Scenario

LINE_PERIOD_S = 2.0


class ProgressView:
    """A progress bar with the traffic so far (terminal), or periodic lines (no terminal)."""

    def __init__(self, console: Console, scenario: Scenario) -> None:
        self.console = console
        self.scenario = scenario
        self.progress: Progress | None = None
        self.task = None
        self.last_line = 0.0

    def __enter__(self) -> "ProgressView":
        if self.console.is_terminal:
            self.progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[traffic]}"),
                TimeElapsedColumn(),
                console=self.console,
            )
            self.progress.start()
            self.task = self.progress.add_task(
                f"{self.scenario.name} ({self.scenario.robots} robots)", total=self.scenario.max_steps, traffic=""
            )
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.progress is not None:
            self.progress.stop()

    def update(self, state: MonitorState) -> None:
        totals = totals_by_category(state.counter.received_table())
        robot = totals.get("robot", {"messages": 0})["messages"]
        world = totals.get("world", {"messages": 0})["messages"]
        traffic = f"robot-to-robot {robot} msgs, world {world} msgs, polls {sum(state.polls)}"
        if self.progress is not None:
            self.progress.update(self.task, completed=state.step, total=state.steps, traffic=traffic)
            return
        now = time.monotonic()
        if state.finished or now - self.last_line >= LINE_PERIOD_S:
            self.console.print(f"step {state.step}/{state.steps}: {traffic}", highlight=False)
            self.last_line = now


def make_view(console: Console, scenario: Scenario, dashboard: bool = True) -> ProgressView:
    """The live view for a monitor writing to ``console``."""
    return ProgressView(console, scenario)


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
