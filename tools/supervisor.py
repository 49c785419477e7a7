"""Starting role processes and always ending them.

Children are started with ``subprocess`` (never ``fork``: a forked child of a process that opened a
Zenoh session hangs), in their own session so a terminal's Ctrl-C reaches only the supervisor,
which then ends them in order. Each child's standard input is a pipe from the supervisor: if the
supervisor dies, even by SIGKILL, the pipe closes and the child stops itself (``--exit-with-parent``).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

from ringtrack.bus.config import announced_endpoints
from ringtrack.bus.runtime import COUNTS_FOLDER_ENV
from ringtrack.tools.console import UsageError

ANNOUNCE_TIMEOUT_S = 20.0
STOP_GRACE_S = 1.5  # SIGTERM, then SIGKILL after this long; everything is gone within 2 s


@dataclass
class Child:
    name: str
    process: subprocess.Popen[bytes]
    stderr_path: Path

    @property
    def pid(self) -> int:
        return self.process.pid

    def stderr_tail(self, lines: int = 5) -> str:
        try:
            text = self.stderr_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])


class Supervisor:
    """Owns a set of child processes; ``stop()`` (also on leaving the ``with`` block) ends them all."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.children: list[Child] = []
        self.ended: set[str] = set()  # children still running when stop() signalled them: not crashes

    def start(self, name: str, argv: Sequence[str], stdout: int | IO[bytes] | None = subprocess.DEVNULL) -> Child:
        stderr_path = self.folder / f"{name}.stderr"
        with stderr_path.open("wb") as stderr:
            process = subprocess.Popen(
                list(argv), stdin=subprocess.PIPE, stdout=stdout, stderr=stderr, start_new_session=True,
                env={**os.environ, COUNTS_FOLDER_ENV: str(self.folder)},
            )
        child = Child(name, process, stderr_path)
        self.children.append(child)
        return child

    def running(self) -> list[Child]:
        return [child for child in self.children if child.process.poll() is None]

    def senders_counts(self) -> dict[str, dict]:
        """What each child's participants said they sent as they left (``<name>.sent.json``, see
        :func:`bus.runtime.write_final_counts`), by participant name."""
        found = {}
        for path in sorted(self.folder.glob("*.sent.json")):
            with contextlib.suppress(OSError, ValueError):
                counts = json.loads(path.read_text())
                found[counts["name"]] = counts
        return found

    def failed(self) -> list[Child]:
        return [child for child in self.children if child.process.poll() not in (None, 0)]

    def crashed(self) -> list[Child]:
        """Children that failed on their own (a non-zero exit other than a stop they were asked
        for): not those ``stop()`` ended, nor those that obeyed a SIGTERM or Ctrl-C."""
        return [child for child in self.children if child.name not in self.ended
                and child.process.returncode not in (0, None, -15, -2, 130)]

    def wait(self, critical: frozenset[str] = frozenset(), poll_s: float = 0.05, stall_s: float | None = None,
             watched: Path | None = None, on_poll: Callable[[], None] | None = None,
             started: Callable[[], bool] | None = None, startup_s: float | None = None) -> None:
        """Wait until every child has exited; return early when a ``critical`` child fails, and raise
        TimeoutError when ``watched`` has not grown for ``stall_s`` seconds (a hung run) once
        ``started()`` says the run is under way, or when it is not under way ``startup_s`` seconds
        after this call (a start-up that hangs); ``on_poll()`` runs at every poll."""
        last_size, last_change = -1, time.monotonic()
        waiting_since = last_change
        while self.running():
            if (startup_s is not None and started is not None and not started()
                    and time.monotonic() - waiting_since > startup_s):
                raise TimeoutError(f"the team did not reach its first step within {startup_s:g} s of start-up")
            if on_poll is not None:
                on_poll()
            if any(child.name in critical for child in self.failed()):
                return
            if stall_s is not None and watched is not None:
                size = watched.stat().st_size if watched.exists() else 0
                if size != last_size or (started is not None and not started()):
                    last_size, last_change = size, time.monotonic()
                elif time.monotonic() - last_change > stall_s:
                    raise TimeoutError(f"{watched} did not grow for {stall_s:g} s")
            time.sleep(poll_s)

    def endpoints(self, path: Path, name: str, timeout_s: float = ANNOUNCE_TIMEOUT_S) -> list[str]:
        """Wait for child ``name`` to announce the endpoints it listens on in ``path`` (written by
        :func:`bus.config.announce_endpoints`) and return them."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if (endpoints := announced_endpoints(path)) is not None:
                return endpoints
            if self.failed():
                raise UsageError(f"the {name} process failed to start: {self.failed()[0].stderr_tail()}")
            time.sleep(0.02)
        raise TimeoutError(f"the {name} process did not announce its endpoints within {timeout_s:.0f} s")

    def stop(self, grace_s: float = STOP_GRACE_S, stop_signal: signal.Signals = signal.SIGTERM) -> None:
        """End every child within ``grace_s`` (+ reaping): ``stop_signal`` to the first child started
        (the leader, whose End makes the others finish on their own), then to whoever is still running
        halfway through the grace, then SIGKILL what is left. The signal tells the children why:
        SIGINT for the user's Ctrl-C (their own sessions keep the terminal's from them), else SIGTERM."""
        started = time.monotonic()
        deadline = started + grace_s
        for phase_end, group in ((started + grace_s / 2, self.children[:1]), (deadline, self.children)):
            for child in group:
                if child.process.poll() is None:
                    self.ended.add(child.name)
                    with contextlib.suppress(ProcessLookupError):
                        child.process.send_signal(stop_signal)
            while self.running() and time.monotonic() < phase_end:
                time.sleep(0.01)
        for child in self.children:
            remaining = max(0.0, deadline - time.monotonic())
            try:
                child.process.wait(remaining)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    child.process.kill()
                child.process.wait()
        for child in self.children:
            if child.process.stdin is not None:
                with contextlib.suppress(OSError):
                    child.process.stdin.close()

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.stop()


class Terminated(Exception):
    """SIGTERM received."""


@contextlib.contextmanager
def terminate_as_exception() -> Iterator[None]:
    """Turn SIGTERM into :class:`Terminated` (and keep SIGINT as KeyboardInterrupt) inside the block."""

    def handler(number: int, frame: object) -> None:
        raise Terminated()

    if threading.current_thread() is not threading.main_thread():
        yield  # signals reach only the main thread; a caller in another thread handles its own
        return
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
