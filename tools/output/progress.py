"""Progress of a long study, counted in trials: a rich bar with its ETA on a terminal, a plain line
every ``every_s`` seconds (and at the end) when stderr is a pipe or a file, nothing when quiet."""

from __future__ import annotations

import time
from types import TracebackType

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from ringtrack.tools.output.console import err

LINE_EVERY_S = 10.0  # seconds between the plain progress lines written off a terminal


def duration(seconds: float) -> str:
    """``1h02m``, ``1m20s`` or ``45s``: a duration (seconds) as a progress line shows it."""
    whole = round(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    return f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"


class TrialProgress:
    """Trials done of ``total`` (``done`` of them before this process started, e.g. read from a
    journal), shown on ``console`` as a context manager: on a terminal a bar with the count, the time
    elapsed and the time remaining; elsewhere a line ``LABEL: 40/120 trials, 33%, eta 1m20s`` every
    ``every_s`` seconds and once at the end; with ``quiet`` nothing. The ETA (seconds) assumes the
    trials left run at the pace of those run since the start."""

    def __init__(self, label: str, total: int, done: int = 0, quiet: bool = False, console: Console = err,
                 every_s: float = LINE_EVERY_S) -> None:
        self.label, self.total, self.done, self.first = label, total, done, done
        self.quiet, self.console, self.every_s = quiet, console, every_s
        self.started = self.last_line = time.monotonic()
        self.shown: int | None = None  # the count the last plain line showed
        self.bar: Progress | None = None
        self.task: TaskID | None = None

    def __enter__(self) -> TrialProgress:
        if not self.quiet and self.console.is_terminal:
            self.bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                TimeElapsedColumn(), TimeRemainingColumn(), console=self.console)
            self.bar.start()
            self.task = self.bar.add_task(f"{self.label} (trials)", total=self.total, completed=self.done)
        return self

    def advance(self, trials: int) -> None:
        """``trials`` more trials are done."""
        self.done += trials
        if self.bar is not None and self.task is not None:
            self.bar.update(self.task, completed=self.done)
        elif not self.quiet and time.monotonic() - self.last_line >= self.every_s:
            self.line()

    def line(self) -> None:
        """Write the plain progress line now."""
        self.last_line, self.shown = time.monotonic(), self.done
        share = self.done / self.total if self.total else 1.0
        self.console.print(f"{self.label}: {self.done}/{self.total} trials, {share:.0%}, eta {self.eta()}",
                           highlight=False, markup=False)

    def eta(self) -> str:
        """The time remaining, or ``?`` before any trial ran here."""
        ran = self.done - self.first
        if self.done >= self.total:
            return duration(0)
        if ran <= 0:
            return "?"
        return duration((time.monotonic() - self.started) / ran * (self.total - self.done))

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        if self.bar is not None:
            self.bar.stop()
        elif not self.quiet and kind is None and self.shown != self.done:  # the end, unless just shown
            self.line()
