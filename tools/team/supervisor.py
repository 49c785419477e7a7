"""Starting role processes and always ending them.

Children are started with ``subprocess``, or forked by the launcher (:mod:`tools.team.launcher`), a
child of the supervisor that has imported a robot's code once and opened no Zenoh session (a
forked child of a process that opened one hangs). Either way each runs in its own session, so a
terminal's Ctrl-C reaches only the supervisor, which then ends them in order, by pid (a forked
child through a pidfd, which cannot name a reused pid). Each child's standard input is a pipe from
the supervisor: if the supervisor dies, even by SIGKILL, the pipe closes and the child stops itself
(``--exit-with-parent``).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

from ringtrack.bus.config import announced_endpoints
from ringtrack.bus.runtime import COUNTS_FOLDER_ENV
from ringtrack.tools.output.console import UsageError

ANNOUNCE_TIMEOUT_S = 20.0
STOP_GRACE_S = 1.5  # SIGTERM, then SIGKILL after this long; everything is gone within 2 s
LAUNCH_TIMEOUT_S = 60.0  # the launcher's imports and one fork, on a machine as busy as CI's
ROLE_ENTRY_POINT = "ringtrack.tools.cli:main"  # what a role process runs: the ringtrack command
ROLE_COMMAND = [sys.executable, "-m", "ringtrack.tools.cli"]  # loads the given role command's module only
LAUNCHER_COMMAND = [sys.executable, "-m", "ringtrack.tools.team.launcher"]
FORK_WORKS = hasattr(os, "fork") and hasattr(os, "pidfd_open")  # Linux: the launcher can be used


class Forked:
    """A child the launcher forked, with the part of :class:`subprocess.Popen` the supervisor uses.
    Its exit code comes from the launcher (its parent); signals go through a pidfd."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.returncode: int | None = None
        self.stdin: IO[bytes] | None = None  # the lifeline is shared: the launcher's owner closes it
        self.orphan = False  # the launcher is gone: no exit code will come
        self._ended = threading.Event()
        try:
            self.pidfd: int | None = os.pidfd_open(pid)
        except ProcessLookupError:  # ended already; its exit code is on its way
            self.pidfd = None

    def ended(self, returncode: int) -> None:
        self.returncode = returncode
        self._ended.set()

    def poll(self) -> int | None:
        if self.returncode is None and self.orphan and (
                self.pidfd is None or select.select([self.pidfd], [], [], 0)[0]):
            self.ended(1)  # an orphan that has ended (its pidfd is readable): its code is lost with the launcher
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while (code := self.poll()) is None:
            left = 0.05 if deadline is None else min(0.05, deadline - time.monotonic())
            if left <= 0:
                raise subprocess.TimeoutExpired(f"pid {self.pid}", timeout or 0.0)
            self._ended.wait(left)
        return code

    def send_signal(self, number: int) -> None:
        if self.returncode is None and self.pidfd is not None:
            with contextlib.suppress(ProcessLookupError):
                signal.pidfd_send_signal(self.pidfd, number)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class Launcher:
    """The launcher process and the children it forked (see :mod:`tools.team.launcher`)."""

    def __init__(self, folder: Path, env: dict[str, str]) -> None:
        lifeline, self.lifeline = os.pipe()
        self.stderr_path = folder / "launcher.stderr"
        with self.stderr_path.open("wb") as stderr:
            self.process = subprocess.Popen(
                [*LAUNCHER_COMMAND, str(folder), "--lifeline", str(lifeline)], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=stderr, pass_fds=(lifeline,), start_new_session=True, env=env,
            )
        os.close(lifeline)
        self.children: dict[int, Forked] = {}
        self.replies: queue.Queue[dict] = queue.Queue()
        self.lock = threading.Lock()  # one fork request at a time: replies come in request order
        threading.Thread(target=self._read, name="launcher-reports", daemon=True).start()

    def fork(self, roles: Sequence[tuple[str, Sequence[str]]]) -> list[Forked]:
        """Have the launcher fork one role process per ``(name, role arguments)``, all requested at once."""
        lines = [json.dumps({"name": name, "argv": list(argv)}) + "\n" for name, argv in roles]
        forked = []
        with self.lock:
            assert self.process.stdin is not None
            try:
                self.process.stdin.write("".join(lines).encode())
                self.process.stdin.flush()
                replies = [self.replies.get(timeout=LAUNCH_TIMEOUT_S) for _ in roles]
            except (OSError, queue.Empty):
                replies = [{"error": f"the launcher did not answer within {LAUNCH_TIMEOUT_S:g} s"}]
        for reply in replies:
            if "pid" not in reply:
                raise UsageError(f"cannot start the {reply.get('name', 'robot')} process: {reply.get('error')}; see "
                                 f"{self.stderr_path}")
            forked.append(self.children[reply["pid"]])
        return forked

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            message = json.loads(line)
            if "returncode" in message:
                self.children[message["pid"]].ended(message["returncode"])
                continue
            if "pid" in message:
                self.children[message["pid"]] = Forked(message["pid"])
            self.replies.put(message)
        for child in list(self.children.values()):
            child.orphan = True
        self.replies.put({"error": "the launcher exited"})

    def close(self, grace_s: float) -> None:
        """Close the lifeline and the launcher's input (it then ends once its children have) and reap it."""
        with contextlib.suppress(OSError):
            os.close(self.lifeline)
        with contextlib.suppress(OSError):
            assert self.process.stdin is not None
            self.process.stdin.close()
        try:
            self.process.wait(grace_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for child in self.children.values():
            if child.pidfd is not None:
                os.close(child.pidfd)
                child.pidfd = None


@dataclass
class Child:
    name: str
    process: subprocess.Popen[bytes] | Forked
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
        self.spared: set[int] = set()  # pids of children a nemesis ended on purpose: not failures
        self.launcher: Launcher | None = None
        self.leader: str | None = None  # the child stop() signals first (None: the first started)

    @property
    def env(self) -> dict[str, str]:
        return {**os.environ, COUNTS_FOLDER_ENV: str(self.folder)}

    def start(self, name: str, argv: Sequence[str], stdout: int | IO[bytes] | None = subprocess.DEVNULL) -> Child:
        stderr_path = self.folder / f"{name}.stderr"
        with stderr_path.open("wb") as stderr:
            process = subprocess.Popen(
                list(argv), stdin=subprocess.PIPE, stdout=stdout, stderr=stderr, start_new_session=True, env=self.env,
            )
        child = Child(name, process, stderr_path)
        self.children.append(child)
        return child

    def preload(self) -> None:
        """Start the launcher now (it imports while other processes start); :meth:`fork` needs it."""
        if self.launcher is None:
            self.launcher = Launcher(self.folder, self.env)

    def fork(self, roles: Sequence[tuple[str, Sequence[str]]]) -> list[Child]:
        """Start one role process per ``(name, arguments of ringtrack.tools.cli)``, forked by the
        launcher (standard output discarded)."""
        self.preload()
        assert self.launcher is not None
        children = [Child(name, process, self.folder / f"{name}.stderr") for (name, _), process in
                    zip(roles, self.launcher.fork(roles), strict=True)]
        self.children += children
        return children

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
        return [child for child in self.children if child.process.poll() not in (None, 0)
                and child.pid not in self.spared]

    def crashed(self) -> list[Child]:
        """Children that failed on their own (a non-zero exit other than a stop they were asked
        for): not those ``stop()`` ended, those a nemesis ended (``spared``), nor those that obeyed
        a SIGTERM or Ctrl-C."""
        return [child for child in self.children if child.name not in self.ended and child.pid not in self.spared
                and child.process.returncode not in (0, None, -15, -2, 130)]

    def wait(self, critical: AbstractSet[str] = frozenset(), poll_s: float = 0.05, stall_s: float | None = None,
             watched: Path | None = None, on_poll: Callable[[], None] | None = None,
             started: Callable[[], bool] | None = None, startup_s: float | None = None) -> None:
        """Wait until every child has exited; return early when a ``critical`` child fails (the set is
        read at every poll: its owner may change it), and raise
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
                try:
                    size = watched.stat().st_size
                except FileNotFoundError:  # not written yet, or the monitor's --log check removing its probe
                    size = 0
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
        """End every child within ``grace_s`` (+ reaping): ``stop_signal`` to the ``leader`` (else the first
        child started), whose End makes the others finish on their own, then to whoever is still running
        halfway through the grace, then SIGKILL what is left. The signal tells the children why:
        SIGINT for the user's Ctrl-C (their own sessions keep the terminal's from them), else SIGTERM."""
        started = time.monotonic()
        deadline = started + grace_s
        leader = [child for child in self.children if child.name == self.leader] or self.children[:1]
        for phase_end, group in ((started + grace_s / 2, leader), (deadline, self.children)):
            for child in group:
                if child.process.poll() is None:
                    self.ended.add(child.name)
                    with contextlib.suppress(ProcessLookupError):
                        child.process.send_signal(stop_signal)
            while self.running() and time.monotonic() < phase_end:
                time.sleep(0.01)
        for child in self.children:
            with contextlib.suppress(subprocess.TimeoutExpired):
                child.process.wait(max(0.0, deadline - time.monotonic()))
        for child in self.children:  # every one left is killed at once, then all are reaped
            if child.process.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    child.process.kill()
        for child in self.children:
            child.process.wait()
        for child in self.children:
            if child.process.stdin is not None:
                with contextlib.suppress(OSError):
                    child.process.stdin.close()
        if self.launcher is not None:
            self.launcher.close(grace_s)

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
