"""``spawn``'s start-up frame, drawn before any process starts, and its hand-over to the monitor.

The monitor draws the dashboard, but only once it has started (an interpreter, Zenoh, its session:
seconds on a loaded machine). So ``spawn`` draws the start-up frame itself, before it starts the
first process, and keeps it up to date (elapsed time, what it is doing) until the monitor is ready
to draw. The terminal then changes hands through one file, which ``spawn`` writes before it starts
the monitor with the time its frame counts from (``time.monotonic()``, one clock for every process
of the machine); the monitor takes that time for its own start-up frame, writes ``ready`` into the
file when it is ready to draw and waits until the file is gone (:func:`take_over`); ``spawn``, once
every process is started, erases its frame and removes the file (:class:`StartupView`). One of them
draws at any time.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from types import TracebackType

from rich.console import Console
from rich.live import Live

from ringtrack.tools.dashboard.dashboard import Dashboard
from ringtrack.tools.monitor.state import TeamModel, startup_names
from ringtrack.world.scenario import Scenario

HANDOVER_WAIT_S = 30.0  # the monitor draws after this long even if nobody released the terminal
POLL_S = 0.02
READY = "ready"


def started_at(path: Path) -> float | None:
    """The ``time.monotonic()`` the start-up frame counts from, as ``spawn`` wrote it to ``path``."""
    try:
        return float(path.read_text())
    except (OSError, ValueError):
        return None


def take_over(path: Path, timeout_s: float = HANDOVER_WAIT_S, give_up: threading.Event | None = None) -> bool:
    """The monitor's side: say it is ready to draw (``ready`` in ``path``) and wait until the process
    that draws the start-up frame removes the file, at most ``timeout_s`` or until ``give_up`` is set
    (the monitor is ending); returns whether the file was removed."""
    temporary = path.with_name(f".{path.name}.partial")
    temporary.write_text(READY)
    os.replace(temporary, path)  # whole: spawn reads either its own time or "ready"
    deadline = time.monotonic() + timeout_s
    while path.exists():
        if time.monotonic() > deadline or (give_up is not None and give_up.is_set()):
            return False
        time.sleep(POLL_S)
    return True


class StartupView:
    """``spawn``'s side: a start-up frame of ``scenario`` (every participant awaited, :attr:`note`
    saying what is being started) on ``console``, redrawn a few times a second from the moment the
    ``with`` block is entered, and ``handover`` written with the time it counts from. After
    :meth:`started_all`, as soon as the monitor has written ``ready`` there, the frame is erased and
    the file removed; leaving the block does the same (a start-up that failed or was interrupted: the
    monitor may still draw its last frame and print its report)."""

    def __init__(self, console: Console, scenario: Scenario, clock: str, handover: Path) -> None:
        self.model = TeamModel(scenario, clock)
        self.model.expected = startup_names(scenario)
        self.handover = handover
        self.live = Live(Dashboard(self.model), console=console, transient=True, refresh_per_second=4,
                         redirect_stdout=False)
        self._all_started = threading.Event()
        self._stopped = threading.Event()
        self._watcher = threading.Thread(target=self._watch, name="ringtrack-startup", daemon=True)

    @property
    def note(self) -> str:
        return self.model.note

    @note.setter
    def note(self, text: str) -> None:
        """What the start-up is doing, shown under the participants from the next redraw on (the caller
        never writes to the terminal itself: a terminal that blocks holds up only the redraws)."""
        self.model.note = text

    def __enter__(self) -> StartupView:
        self.live.start(refresh=True)  # the first frame, before anything else happens
        self.handover.write_text(repr(self.model.started))
        self._watcher.start()
        return self

    def started_all(self) -> None:
        """Every process is started: hand the terminal over as soon as the monitor asks for it."""
        self._all_started.set()

    def _watch(self) -> None:
        while not self._stopped.is_set():
            if self._all_started.is_set() and self._monitor_ready():
                self._stop()
                return
            self._stopped.wait(POLL_S)

    def _monitor_ready(self) -> bool:
        try:
            return self.handover.read_text() == READY
        except OSError:
            return False

    def _stop(self) -> None:
        self._stopped.set()
        self.live.stop()  # transient: the frame is erased, the monitor draws from the same line
        self.handover.unlink(missing_ok=True)

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self._stop()
        self._watcher.join()
