"""Run one team inside a private network namespace and count the bytes its loopback carried while it
stepped (from its first logged step to its end): every packet of every link (Zenoh frames, TLS
records, TCP/IP headers, acknowledgements), and nothing of any other process on the machine. The
start-up (sessions, TLS handshakes, gossip, declarations) is left out: it does not grow with the
run.

    unshare --net --map-root-user -- python -m ringtrack.tools.bench.wire OUT.json SCENARIO.toml RUNS [SECURE_DIR]

writes a :class:`WireRun` (the team's result, ``wire_bytes`` while stepping and ``startup_wire_bytes``
before the first step) to ``OUT.json``.
``ringtrack bench emulator`` starts it; it needs ``unshare`` (util-linux) and either root or
unprivileged user namespaces.
"""

from __future__ import annotations

import fcntl
import os
import socket
import struct
import sys
import threading
import time
from pathlib import Path

import msgspec

from ringtrack.tools.output.files import write_json
from ringtrack.tools.team.plan import TeamPlan, TeamResult
from ringtrack.tools.team.spawn import FirstStep, spawn_team
from ringtrack.world.scenario import load_scenario


class WireRun(msgspec.Struct):
    """A team's result and the bytes its loopback carried: while it stepped, and before its first step."""

    team: TeamResult
    wire_bytes: int | None = None
    startup_wire_bytes: int | None = None

    @property
    def wire_bytes_per_message(self) -> float:
        """Bytes on the wire per message of the run (NaN when not measured or nothing was sent)."""
        messages = sum(entry["messages"] for entry in self.team.by_kind.values())
        return self.wire_bytes / messages if messages and self.wire_bytes is not None else float("nan")


NETWORK_DEVICES = Path("/proc/self/net/dev")  # this namespace's counters (/sys shows the mounter's)
SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1
UNSHARE = ["unshare", "--net", "--map-root-user", "--"]


def loopback_up() -> None:
    """Bring up ``lo`` (down in a new network namespace)."""
    with socket.socket() as handle:
        request = struct.pack("16sh", b"lo", 0)
        flags = struct.unpack("16sh", fcntl.ioctl(handle, SIOCGIFFLAGS, request))[1]
        fcntl.ioctl(handle, SIOCSIFFLAGS, struct.pack("16sh", b"lo", flags | IFF_UP))


def transmitted() -> int:
    """Bytes ``lo`` has sent in this network namespace (every packet crosses it once)."""
    for line in NETWORK_DEVICES.read_text().splitlines():
        device, _, counters = line.partition(":")
        if device.strip() == "lo":
            return int(counters.split()[8])
    raise RuntimeError("no loopback device in /proc/self/net/dev")


def main(out: Path, scenario_path: str, runs: Path, secure: Path | None) -> None:
    loopback_up()
    before = transmitted()
    at_first_step: list[int] = []
    log_path = runs / f"wire-{os.getpid()}.jsonl"
    stop = threading.Event()
    first_step = FirstStep(log_path, time.perf_counter())

    def watch() -> None:
        while not stop.wait(0.005):
            first_step()
            if first_step.after is not None:
                at_first_step.append(transmitted())
                return

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        result = spawn_team(TeamPlan(scenario=load_scenario(scenario_path), clock="lockstep", runs=runs,
                                     log_path=log_path, dashboard=False, quiet=True, secure=secure))
    finally:
        stop.set()
        watcher.join()
    start = at_first_step[0] if at_first_step else before
    write_json(out, WireRun(result, wire_bytes=transmitted() - start, startup_wire_bytes=start - before))


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]) if len(sys.argv) > 4 else None)
