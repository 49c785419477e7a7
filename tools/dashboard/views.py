"""What the monitor shows while a team runs, and its end-of-run report.

On a terminal the live dashboard (:mod:`tools.dashboard.dashboard`), refreshed a few times per second by the
monitor and never per message; without one, a plain summary line every few seconds. Either is
written by a drawer thread of its own, so a display nobody reads (a full pipe) never holds up the
monitor, and through it the robots.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Generic, TypeVar

from rich.console import Console
from rich.live import Live
from rich.table import Table

from ringtrack.agents.summary import RunSummary
from ringtrack.bus.counting import category_of, robot_link_totals
from ringtrack.bus.keys import robot_index
from ringtrack.bus.messages import EndReason
from ringtrack.tools.dashboard.dashboard import Dashboard
from ringtrack.tools.dashboard.startup import take_over
from ringtrack.tools.monitor.monitor import COMPARED, MonitorReport
from ringtrack.tools.monitor.state import TeamModel, messages_saved
from ringtrack.tools.output.console import BUSIEST, SUMMARISED_ABOVE, show

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
    stuck on its output then finishes on its own once the stream is read (it is a daemon thread).
    With ``handover`` (spawn draws the start-up frame until the monitor is ready) the drawer first
    waits for the terminal (:func:`tools.dashboard.startup.take_over`); the monitor meanwhile goes on."""

    def __init__(self, console: Console, model: TeamModel, dashboard: bool,
                 final_wait_s: float = FINAL_WAIT_S, handover: Path | None = None) -> None:
        self.console = console
        self.model = model
        self.dashboard = dashboard
        self.final_wait_s = final_wait_s
        self.handover = handover
        self.closing = threading.Event()  # set on leaving: a drawer still waiting for the terminal stops waiting
        self.last_line = -LINE_PERIOD_S
        self.mailbox: Mailbox[TeamModel | str] = Mailbox()
        self.drawer = threading.Thread(target=self._draw, name="ringtrack-drawer", daemon=True)

    def __enter__(self) -> LiveView:
        self.drawer.start()
        if self.dashboard:
            self.refresh()  # the first frame at once (before the first step: the start-up view)
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.closing.set()
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
        if self.handover is not None:
            take_over(self.handover, give_up=self.closing)
        live = Live(console=self.console, auto_refresh=False, redirect_stdout=False, redirect_stderr=False)
        live.start()
        try:
            while (snapshot := self.mailbox.take()) is not None:
                assert isinstance(snapshot, TeamModel)  # a dashboard's mailbox holds models only
                live.update(Dashboard(snapshot), refresh=True)
        finally:
            live.stop()  # draws the last snapshot once more, in full


CATEGORY_NAMES = {"robot": "robot-to-robot", "world": "world", "estimation": "estimation", "monitoring": "monitoring"}
CATEGORY_HELP = ("robot-to-robot: the polls' requests and replies, and pushed beliefs; world: measurements, "
                 "commands, ticks and the end; estimation: ranges to and estimates from the fusion centre; "
                 "monitoring: statistics and fault notices the processes send the monitor (not compared: a final "
                 "statistics message cannot count itself). seen: by the monitor; sent: as the senders counted")

Counts = list[tuple[int, int]]  # (messages, bytes) per column of a row


def summarised(rows: list[tuple[str, Counts]], all_rows: bool, busy: Callable[[Counts], int],
               keep: Callable[[str], bool] = lambda _: False) -> list[tuple[str, Counts, str | None]]:
    """``(label, counts, style)`` to show: every row of a table of at most ``SUMMARISED_ABOVE`` (or with
    ``all_rows``); else min, median and max of every column (messages and bytes apart), the
    ``BUSIEST`` rows by ``busy(counts)``, and every row for which ``keep(label)`` (marked red)."""
    if all_rows or len(rows) <= SUMMARISED_ABOVE:
        return [(label, counts, "red" if keep(label) else None) for label, counts in rows]
    columns = len(rows[0][1])
    shown: list[tuple[str, Counts, str | None]] = []
    for name, pick in (("min", min), ("median", statistics.median_low), ("max", max)):
        shown.append((f"{name} of {len(rows)}", [(pick(counts[column][0] for _, counts in rows),
                                                  pick(counts[column][1] for _, counts in rows))
                                                 for column in range(columns)], "bold"))
    busiest = sorted(rows, key=lambda row: -busy(row[1]))[:BUSIEST]
    shown += [(f"busiest: {label}", counts, None) for label, counts in busiest]
    shown += [(label, counts, "red") for label, counts in rows if keep(label)]
    return shown


def per_robot_table(rows: list, all_robots: bool = False) -> Table:
    """Robot-to-robot messages and bytes each robot sent and received, and its world traffic; above
    ``SUMMARISED_ABOVE`` robots only min/median/max and the busiest, unless ``all_robots``."""
    robots = sorted({name for _, source, destination, _, _ in rows for name in (source, destination)
                     if robot_index(name) is not None}, key=lambda name: robot_index(name) or 0)
    table = Table(title="per robot (messages/bytes)", caption="robot-to-robot sent and received; world: "
                  "measurements from it, commands to it", caption_justify="left")
    for column in ("robot", "sent", "received", "from world", "to world"):
        table.add_column(column, justify="right")
    counted = [(name, robot_counts(rows, name)) for name in robots]
    for label, counts, style in summarised(counted, all_robots, lambda counts: counts[0][0] + counts[1][0]):
        table.add_row(label, *(f"{messages}/{size}" for messages, size in counts), style=style)
    return table


def robot_counts(rows: list, name: str) -> Counts:
    """``(messages, bytes)`` of robot ``name``: robot-to-robot sent and received, from the world and
    to the world, summed over traffic rows ``(kind, source, destination, messages, bytes)``."""
    totals = [[0, 0] for _ in range(4)]
    for kind, source, destination, count, size in rows:
        robot = category_of(kind) == "robot"
        for column, hit in enumerate((robot and source == name, robot and destination == name,
                                      source == "world" and destination == name,
                                      source == name and destination == "world")):
            if hit:
                totals[column][0] += count
                totals[column][1] += size
    return [(messages, size) for messages, size in totals]


def per_link_table(report: MonitorReport, all_robots: bool = False) -> Table:
    """Robot-to-robot messages and bytes on every directed link that carried any, as the monitor saw
    them and as their senders counted them, ordered by sender then receiver (2N rows for a ring of N;
    above ``SUMMARISED_ABOVE`` links min/median/max and the busiest, unless ``all_robots``); a link
    where the two differ is red, and always shown."""
    seen, said = robot_link_totals(report.received), robot_link_totals(report.sender_rows())
    table = Table(title="robot-to-robot traffic per link (messages/bytes)")
    for column in ("link", "seen", "sent"):
        table.add_column(column, justify="right")
    none = {"messages": 0, "bytes": 0}
    counted = []
    for source, destination in sorted(seen.keys() | said.keys(), key=lambda pair: tuple(map(robot_index, pair))):
        mine, theirs = seen.get((source, destination), none), said.get((source, destination), none)
        counted.append((f"{source} > {destination}", [(entry["messages"], entry["bytes"]) for entry in (mine, theirs)]))
    differing = {label for label, counts in counted if counts[0] != counts[1]}
    for label, counts, style in summarised(counted, all_robots, lambda counts: counts[0][0],
                                           keep=lambda label: label in differing):
        table.add_row(label, *(f"{messages}/{size}" for messages, size in counts), style=style)
    return table


def outcome_lines(outcome: RunSummary, robot_messages: int) -> list[str]:
    """Ctime, Com-bar (against the constant strategy's 1) and the robot-to-robot messages saved,
    from a run summary (:func:`agents.summary.summarise`), each line under 80 columns."""
    steps, robots = outcome.steps, outcome.robots
    converged = f"converged at step {outcome.ctime} (Ctime)" if outcome.converged else \
        f"did not converge in {steps} steps"
    com_bar = f"Com-bar {outcome.com_bar:.3f} (constant 1)" if outcome.com_bar is not None else \
        "Com-bar - (not converged)"
    saved, share = messages_saved(robots, steps, robot_messages)
    return [f"outcome: {converged}; {com_bar}",
            f"robot-to-robot messages {robot_messages}: {saved} saved ({share:.0%}) against the constant strategy"]


def print_report(console: Console, report: MonitorReport, outcome: RunSummary | None = None,
                 all_robots: bool = False) -> None:
    """Traffic by category as the monitor saw it and as the senders counted it, per robot and per
    robot-to-robot link (summarised above ``SUMMARISED_ABOVE`` robots unless ``all_robots``), the
    run's outcome (``outcome``: its summary, when it has steps); the verdict compares every link of
    the categories in ``COMPARED``."""
    table = Table(title="traffic by category (payload bytes)", caption=CATEGORY_HELP, caption_justify="left")
    for column in ("category", "msgs seen", "bytes seen", "msgs sent", "bytes sent", "B/msg"):
        table.add_column(column, justify="right")
    mine, theirs = report.monitor_totals(), report.sender_totals()
    for category in (*COMPARED, "monitoring"):
        seen = mine.get(category, {"messages": 0, "bytes": 0})
        sent = theirs.get(category, {"messages": 0, "bytes": 0})
        per_message = f"{seen['bytes'] / seen['messages']:.1f}" if seen["messages"] else "-"
        compared = category in COMPARED
        table.add_row(CATEGORY_NAMES[category], str(seen["messages"]), str(seen["bytes"]),
                      str(sent["messages"]) if compared else "-", str(sent["bytes"]) if compared else "-", per_message)
    show(table, console)
    show(per_robot_table(report.received, all_robots), console)
    show(per_link_table(report, all_robots), console)
    verdict = "equal on every link" if report.consistent() else "DIFFERENT"
    rejected = ", ".join(f"{reason} {count}" for reason, count in report.rejected.items()) or "none"
    ending = f"{report.end.reason.text(report.end.step)} after {report.end.step} steps" if report.end \
        else "no end record"
    if report.end is not None and report.end.reason is EndReason.CONVERGED:
        ending += f" (Ctime = {report.end.step} steps)"
    console.print(f"run: {ending}; rejected: {rejected}; late: {report.late}", highlight=False)
    console.print(f"monitor vs senders: {verdict}", highlight=False)
    for line in report.books().lines():
        console.print(f"  {line}", highlight=False)
    if report.superseded:
        fenced = sum(row[3] for row in report.superseded)
        console.print(f"replaced lives: {fenced} messages of robots' older lives dropped at the door "
                      f"({', '.join(sorted({row[1] for row in report.superseded}))})", highlight=False)
    if (reason := report.distrust()) is not None:
        console.print(f"outcome: not trusted: {reason}", highlight=False)
    elif outcome is not None:
        print_outcome(console, outcome, report)


def print_outcome(console: Console, outcome: RunSummary, report: MonitorReport) -> None:
    """The lines of :func:`outcome_lines` for a run summary and the robot-to-robot messages seen."""
    for line in outcome_lines(outcome, report.monitor_totals().get("robot", {"messages": 0})["messages"]):
        console.print(line, highlight=False)
