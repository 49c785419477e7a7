"""Run one team inside a private network namespace and count the bytes its loopback carried: every
packet of every link (Zenoh frames, TLS records, TCP/IP headers, acknowledgements), and nothing of
any other process on the machine.

    unshare --net --map-root-user -- python -m ringtrack.tools.wire OUT.json SCENARIO.toml RUNS [SECURE_DIR]

writes the summary of :func:`ringtrack.tools.spawn.spawn_team` plus ``wire_bytes`` to ``OUT.json``.
``ringtrack bench emulator`` starts it; it needs ``unshare`` (util-linux) and either root or
unprivileged user namespaces.
"""

from __future__ import annotations

import fcntl
import socket
import struct
import sys
from pathlib import Path

from ringtrack.tools.console import write_json
from ringtrack.tools.spawn import spawn_team
from ringtrack.world.scenario import load_scenario

LOOPBACK_TX = Path("/sys/class/net/lo/statistics/tx_bytes")
SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1
UNSHARE = ["unshare", "--net", "--map-root-user", "--"]


def loopback_up() -> None:
    """Bring up ``lo`` (down in a new network namespace)."""
    with socket.socket() as handle:
        request = struct.pack("16sh", b"lo", 0)
        flags = struct.unpack("16sh", fcntl.ioctl(handle, SIOCGIFFLAGS, request))[1]
        fcntl.ioctl(handle, SIOCSIFFLAGS, struct.pack("16sh", b"lo", flags | IFF_UP))


def main(out: Path, scenario_path: str, runs: Path, secure: Path | None) -> None:
    loopback_up()
    before = int(LOOPBACK_TX.read_text())
    result = spawn_team(load_scenario(scenario_path), clock="lockstep", runs=runs, dashboard=False, quiet=True,
                        secure=secure)
    result["wire_bytes"] = int(LOOPBACK_TX.read_text()) - before
    write_json(out, result)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3]), Path(sys.argv[4]) if len(sys.argv) > 4 else None)
