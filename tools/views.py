"""What the monitor shows while a team runs, and its end-of-run report.

On a terminal the live dashboard (:mod:`tools.dashboard`), refreshed a few times per second by the
monitor and never per message; without one, a plain summary line every few seconds. Either is
written by a drawer thread of its own, so a display nobody reads (a full pipe) never holds up the
monitor, and through it the robots.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Generic, TypeVar

from rich.console import Console
from rich.live import Live
from rich.table import Table

from ringtrack.bus.counting import category_of, robot_link_totals
from ringtrack.bus.keys import robot_index
from ringtrack.tools.dashboard import Dashboard, TeamModel
from ringtrack.tools.monitor import COMPARED, MonitorReport

LINE_PERIOD_S = 2.0
FINAL_WAIT_S = 5.0  # leaving the view waits at most this long (wall seconds) for the drawer's last frame

Frame = TypeVar("Frame")


class Mailbox(Generic[Frame]):
    """A single slot between a producer that must never wait and the one consumer that draws: a
    frame put while the previous one is still waiting replaces it (that frame is skipped)."""

    def __init__(self) -> None:
        self._ready = threading.Condition()
        self._frame: Frame | None = None
        self._closed = False

    def put(self, frame: Frame) -> None:
        with self._ready:
            self._frame = frame
            self._ready.notify()

    def close(self) -> None:
        """No more frames: :meth:`take` returns the one still waiting, then None."""
        with self._ready:
            self._closed = True
            self._ready.notify()

    def take(self) -> Frame | None:
        """The latest frame, waiting for one; None once closed and empty."""
        with self._ready:
            self._ready.wait_for(lambda: self._frame is not None or self._closed)
            frame, self._frame = self._frame, None
            return frame


class LiveView:
    """The display of a :class:`~tools.dashboard.TeamModel`: with a dashboard, a rich Live redrawn
    with a snapshot of the model at each :meth:`refresh` (the caller decides how often, never per
    message); without, a plain summary line every ``LINE_PERIOD_S`` seconds and at the end.

    :meth:`refresh` only leaves the frame in a :class:`Mailbox` and returns: a drawer thread writes
    it to the console, and a frame is skipped while the previous one is still being written.
    Leaving the ``with`` block waits at most ``final_wait_s`` for the last frame; a drawer still
    stuck on its output then finishes on its own once the stream is read (it is a daemon thread)."""

    def __init__(self, console: Console, model: TeamModel, dashboard: bool,
                 final_wait_s: float = FINAL_WAIT_S) -> None:
        self.console = console
        self.model = model
        self.dashboard = dashboard
        self.final_wait_s = final_wait_s
        self.last_line = -LINE_PERIOD_S
        self.mailbox: Mailbox[TeamModel | str] = Mailbox()
        self.drawer = threading.Thread(target=self._draw, name="ringtrack-drawer", daemon=True)

    def __enter__(self) -> LiveView:
        self.drawer.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.mailbox.close()
        self.drawer.join(self.final_wait_s)

    def refresh(self, final: bool = False) -> None:
        """Hand the drawer the current frame (``final``: the last one); never waits for the output."""
        if self.dashboard:
            self.mailbox.put(self.model.snapshot())
            return
        now = time.monotonic()
        if final or now - self.last_line >= LINE_PERIOD_S:
            self.mailbox.put(self.model.summary_line())
            self.last_line = now

    def _draw(self) -> None:
        """The drawer thread: write the latest frame whenever one waits, until the mailbox closes. The
        Live redirects no output: a print elsewhere must never wait on the drawer's stream."""
        if not self.dashboard:
            while (line := self.mailbox.take()) is not None:
                self.console.print(line, highlight=False, soft_wrap=True)
            return
        live = Live(console=self.console, auto_refresh=False, redirect_stdout=False, redirect_stderr=False)
        live.start()
        try:
            while (snapshot := self.mailbox.take()) is not None:
                live.update(Dashboard(snapshot), refresh=True)
        finally:
            live.stop()  # draws the last snapshot once more, in full


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
            _sum(rows, lambda kind, source, _, name=name: category_of(kind) == "robot" and source == name),
            _sum(rows, lambda kind, _, destination, name=name: category_of(kind) == "robot" and destination == name),
            _sum(rows, lambda _, source, destination, name=name: source == "world" and destination == name),
            _sum(rows, lambda _, source, destination, name=name: source == name and destination == "world"),
        )
    return table


def _sum(rows: list, match: Callable[[str, str, str], bool]) -> str:
    """``"messages / bytes"`` over the traffic rows whose (kind, source, destination) match."""
    selected = [(count, size) for kind, source, destination, count, size in rows if match(kind, source, destination)]
    return f"{sum(count for count, _ in selected)} / {sum(size for _, size in selected)}"


def per_link_table(report: MonitorReport) -> Table:
    """Robot-to-robot messages and bytes on every directed link that carried any, as the monitor saw
    them and as their senders counted them, ordered by sender then receiver (2N rows for a ring of N);
    a link where the two differ is red."""
    seen, said = robot_link_totals(report.received), robot_link_totals(report.sender_rows())
    table = Table(title="robot-to-robot traffic per link (payload bytes)")
    for column in ("link", "messages seen", "bytes seen", "messages sent", "bytes sent"):
        table.add_column(column, justify="right")
    for source, destination in sorted(seen.keys() | said.keys(), key=lambda pair: tuple(map(robot_index, pair))):
        none = {"messages": 0, "bytes": 0}
        mine, theirs = seen.get((source, destination), none), said.get((source, destination), none)
        table.add_row(f"{source} > {destination}", *(str(entry[field]) for entry in (mine, theirs)
                                                     for field in ("messages", "bytes")),
                      style=None if mine == theirs else "red")
    return table


def print_report(console: Console, report: MonitorReport) -> None:
    """Traffic by category as the monitor saw it and as the senders counted it, per robot and per
    robot-to-robot link; the verdict compares every link of the categories in ``COMPARED``."""
    table = Table(title="traffic (payload bytes)")
    for column in ("category", "messages seen", "bytes seen", "messages sent", "bytes sent", "bytes/message"):
        table.add_column(column, justify="right")
    mine, theirs = report.monitor_totals(), report.sender_totals()
    for category in (*COMPARED, "monitoring"):
        seen = mine.get(category, {"messages": 0, "bytes": 0})
        sent = theirs.get(category, {"messages": 0, "bytes": 0})
        per_message = f"{seen['bytes'] / seen['messages']:.1f}" if seen["messages"] else "-"
        table.add_row(category, str(seen["messages"]), str(seen["bytes"]), str(sent["messages"]),
                      str(sent["bytes"]), per_message)
    console.print(table)
    console.print(per_robot_table(report.received))
    console.print(per_link_table(report))
    verdict = "equal on every link" if report.consistent() else "DIFFERENT"
    rejected = ", ".join(f"{reason} {count}" for reason, count in report.rejected.items()) or "none"
    ending = f"{report.end.reason} after {report.end.step} steps" if report.end else "no end record"
    if report.end is not None and report.end.reason == "converged":
        ending += f" (Ctime = {report.end.step} steps)"
    console.print(f"run: {ending}; monitor vs senders: {verdict}; rejected: {rejected}; late: {report.late}",
                  highlight=False)
