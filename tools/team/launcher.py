"""A preloaded starter of role processes: it imports a robot's code once and forks each robot from it.

A fresh interpreter spends about half a second of CPU importing numpy, Zenoh and the robot's modules
before it opens its session; 64 robot processes on two cores would spend most of a team's start-up
doing that. The launcher (``python -m ringtrack.tools.team.launcher FOLDER --lifeline FD``) imports those modules
once, opens no Zenoh session (a child forked after a session was opened hangs), and forks one child
per request. Each child is a role process like one started with ``python -m ringtrack.tools.cli``:
its own session (``setsid``), its own standard error file ``FOLDER/<name>.stderr``, its own Zenoh
session and identity, its standard output discarded.

Protocol, one JSON object per line:

* standard input (from the supervisor): ``{"name", "argv"}`` (``argv`` the role's arguments after
  ``ringtrack.tools.cli``);
* standard output (to the supervisor): ``{"name", "pid"}`` once a child runs, ``{"pid", "returncode"}``
  once it has ended (``-N`` for signal N, as :class:`subprocess.Popen` reports it), and
  ``{"name", "error"}`` when it cannot be forked.

Every child's standard input is the lifeline, the read end of a pipe whose only writer is the
supervisor: when the supervisor dies, even by SIGKILL, every child reads end of file and stops
itself (``--exit-with-parent``). The launcher ends once its standard input is closed and every
child it forked has ended.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import select
import signal
import sys
import tomllib  # noqa: F401  (preloaded, see below)
import traceback
from collections.abc import Callable
from pathlib import Path

import setproctitle

from ringtrack.tools.team.supervisor import ROLE_COMMAND, ROLE_ENTRY_POINT

# What a robot or world process imports, loaded once (by name: the launcher starts commands, it
# does not depend on them) so that each child starts with it in memory; also what a robot imports
# only once running (the scenario file's parser above, the controller of its first step).
PRELOADED = ("ringtrack.agents.controller", "ringtrack.agents.process", "ringtrack.world.process",
             "ringtrack.tools.cli.robot", "ringtrack.tools.cli.world")

POLL_S = 0.5  # s: the longest the launcher waits before reaping, should a child's SIGCHLD be missed


def _child(request: dict, folder: Path, lifeline: int) -> int:
    """In the forked child: become the role process ``request`` describes; returns its exit code. The
    child then leaves the launcher's loop and ends like any interpreter (not by ``os._exit``: the end
    of its Zenoh runtime delivers what is still queued, such as its final statistics)."""
    try:
        os.setsid()
        signal.set_wakeup_fd(-1)
        for number, handler in ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL),
                                (signal.SIGCHLD, signal.SIG_DFL)):
            signal.signal(number, handler)
        stderr = os.open(folder / f"{request['name']}.stderr", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        stdout = os.open(os.devnull, os.O_WRONLY)
        for source, target in ((lifeline, 0), (stdout, 1), (stderr, 2)):
            os.dup2(source, target)
        os.closerange(3, os.sysconf("SC_OPEN_MAX"))  # the launcher's pipes are not the child's
        sys.argv = [ROLE_COMMAND[-1], *request["argv"]]
        setproctitle.setproctitle(" ".join([*ROLE_COMMAND, *request["argv"]]))
        return entry_point(ROLE_ENTRY_POINT)(list(request["argv"]))
    except SystemExit as done:  # argparse's own exits
        return done.code if isinstance(done.code, int) else 1
    except BaseException:  # noqa: BLE001 - a child must never go on as the launcher
        traceback.print_exc()
        return 1


def _report(message: dict) -> None:
    os.write(1, (json.dumps(message) + "\n").encode())


def _returncode(status: int) -> int:
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def _reap(children: set[int]) -> None:
    """Report every child that has ended."""
    while children:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            children.clear()
            return
        if pid == 0:
            return
        children.discard(pid)
        _report({"pid": pid, "returncode": _returncode(status)})


def serve(folder: Path, lifeline: int) -> int:
    """Fork a child for every request on standard input until it closes and every child has ended;
    returns the launcher's exit code, or, in a child, the child's."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the supervisor ends the children itself, by pid
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # A child's end wakes the loop at once (SIGCHLD through a wake-up pipe), so its exit code is
    # reported without delay; POLL_S bounds the wait should a wake-up be missed.
    woken, wake = os.pipe()
    os.set_blocking(wake, False)
    signal.set_wakeup_fd(wake)
    signal.signal(signal.SIGCHLD, lambda number, frame: None)
    children: set[int] = set()
    pending = b""
    open_input = True
    while open_input or children:
        ready = select.select([0, woken] if open_input else [woken], [], [], POLL_S)[0]
        if woken in ready:
            os.read(woken, 4096)
        if 0 in ready:
            chunk = os.read(0, 65536)
            open_input = bool(chunk)
            pending += chunk
            *lines, pending = pending.split(b"\n")
            for line in lines:
                request = json.loads(line)
                try:
                    pid = os.fork()
                except OSError as error:
                    _report({"name": request["name"], "error": str(error)})
                    continue
                if pid == 0:
                    return _child(request, folder, lifeline)
                children.add(pid)
                _report({"name": request["name"], "pid": pid})
        _reap(children)
    return 0


def entry_point(name: str) -> Callable[[list[str]], int]:
    """The function ``"package.module:function"`` names (imported at most once)."""
    module, _, function = name.partition(":")
    return getattr(importlib.import_module(module), function)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m ringtrack.tools.team.launcher",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="the run folder: children's standard error goes to <name>.stderr")
    parser.add_argument("--lifeline", type=int, required=True, metavar="FD",
                        help="inherited read end of the pipe that becomes every child's standard input")
    args = parser.parse_args()
    for module in PRELOADED:
        importlib.import_module(module)
    entry_point(ROLE_ENTRY_POINT)
    return serve(args.folder, args.lifeline)


if __name__ == "__main__":
    sys.exit(main())
