"""A team spread over three hosts: network namespaces joined by veth links (root only).

Host A (the hub) runs the world and the monitor; hosts B and C run three robots each, packed into
one process per host. B and C reach each other only through A. Two ways to connect them:

* through a Zenoh router (``ringtrack router`` on A): every other process is its client, so
  robot-to-robot traffic between B and C crosses the router;
* directly: every process is a Zenoh peer listening on its host's address, A forwards IP packets,
  and gossip links every pair across the hosts.

Lockstep runs must equal the engine either way, also as a secure team through ``ringtrack router
--secure`` (mutual TLS on every link, the router enforcing the team's access control), and still
complete when nftables drops a share of the packets on B's link (TCP retransmits: loss becomes
delay, never a lost message).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ringtrack.bus.security import create_team
from ringtrack.tools.runlog.log import read_log
from tests.helpers import assert_equals_engine

HANG_S = 600  # seconds a three-host team may take before the test calls it hung
pytestmark = [
    pytest.mark.processes,
    pytest.mark.root,
    pytest.mark.timeout(HANG_S + 120),
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root"),
    pytest.mark.skipif(shutil.which("ip") is None, reason="iproute2 ('ip') is not installed"),
]

PORT = 7447
CONVERGED_AT = 712  # paper-stationary's worked example (docs/algorithms.md oracle 11)


def sh(*command: str) -> None:
    subprocess.run(command, check=True, capture_output=True)


class Hosts:
    """Namespaces ``a``, ``b``, ``c``; b and c each linked to a by a veth pair (10.77.1.0/24 and
    10.77.2.0/24, a holding .1), with routes through a, which forwards."""

    def __init__(self) -> None:
        tag = f"{os.getpid() % 100000}"
        self.names = {host: f"rt{host}{tag}" for host in "abc"}
        self.addresses = {"a": ("10.77.1.1", "10.77.2.1"), "b": ("10.77.1.2",), "c": ("10.77.2.2",)}
        self.devices = {host: (f"va{host}{tag}", f"v{host}a{tag}") for host in "bc"}
        self.processes: list[subprocess.Popen[bytes]] = []
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    def _build(self) -> None:
        for name in self.names.values():
            sh("ip", "netns", "add", name)
            sh("ip", "-n", name, "link", "set", "lo", "up")
        for host, hub_address in (("b", "10.77.1.1"), ("c", "10.77.2.1")):
            outer, inner = self.devices[host]
            sh("ip", "link", "add", outer, "type", "veth", "peer", "name", inner)
            sh("ip", "link", "set", outer, "netns", self.names["a"])
            sh("ip", "link", "set", inner, "netns", self.names[host])
            sh("ip", "-n", self.names["a"], "addr", "add", f"{hub_address}/24", "dev", outer)
            sh("ip", "-n", self.names[host], "addr", "add", f"{self.addresses[host][0]}/24", "dev", inner)
            sh("ip", "-n", self.names["a"], "link", "set", outer, "up")
            sh("ip", "-n", self.names[host], "link", "set", inner, "up")
            sh("ip", "-n", self.names[host], "route", "add", "default", "via", hub_address)
        sh("ip", "netns", "exec", self.names["a"], "sysctl", "-qw", "net.ipv4.ip_forward=1")

    def start(self, host: str, *arguments: str) -> subprocess.Popen[bytes]:
        command = ["ip", "netns", "exec", self.names[host], sys.executable, "-m", "ringtrack.tools.cli"]
        process = subprocess.Popen([*command, *arguments], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                   cwd=Path(__file__).parents[1])
        self.processes.append(process)
        return process

    def wait_listening(self, host: str, address: str, port: int, limit_s: float = 120.0) -> None:
        """Wait until something on ``host`` accepts TCP connections on ``address``:``port`` (a client
        that connects before its router listens exits at once), at most ``limit_s`` seconds."""
        probe = f"import socket; socket.create_connection(({address!r}, {port}), 1).close()"
        deadline = time.monotonic() + limit_s
        while subprocess.run(["ip", "netns", "exec", self.names[host], sys.executable, "-c", probe],
                             capture_output=True).returncode != 0:
            assert time.monotonic() < deadline, f"nothing listens on {address}:{port} of host {host} after {limit_s} s"
            time.sleep(0.2)

    def errors(self) -> list[str]:
        return [process.stderr.read().decode()[-500:] for process in self.processes
                if process.poll() not in (None, 0) and process.stderr is not None]

    def close(self) -> None:
        for process in self.processes:
            if process.poll() is None:
                process.kill()
                process.wait()
        for name in self.names.values():
            subprocess.run(["ip", "netns", "del", name], capture_output=True)


@pytest.fixture
def hosts() -> Iterator[Hosts]:
    created = Hosts()
    try:
        yield created
    finally:
        created.close()


def run_team(hosts: Hosts, log: Path, via_router: bool, steps: int | None = None,
             secure: Path | None = None) -> tuple[list[int], float]:
    """World and monitor on a, robots 0-2 on b and 3-5 on c, through a router on a or as direct
    peers, with the team folder ``secure`` over mutual TLS; at most ``steps`` steps, or until
    convergence. Returns the exit codes and wall seconds."""
    run = f"{os.getpid() & 0xFFFFFFF:08x}"
    protection = [] if secure is None else ["--secure", str(secure)]
    common = ["paper-stationary", "--run", run, "--monitor", *protection]
    common += ["--steps", str(steps)] if steps else []
    protocol = "tcp" if secure is None else "tls"
    hub = [f"{protocol}/{address}:{PORT}" for address in hosts.addresses["a"]]
    world_listen = [flag for endpoint in hub for flag in ("--listen", endpoint)]
    started = time.monotonic()
    # on a loaded machine a hub can take seconds to listen, and a client that finds nobody there exits
    if via_router:
        hosts.start("a", "router", *world_listen, *protection)
        hosts.wait_listening("a", hosts.addresses["a"][0], PORT)
        world = hosts.start("a", "world", *common, "--mode", "client", "--connect", hub[0])
    else:
        world = hosts.start("a", "world", *common, *world_listen)
        hosts.wait_listening("a", hosts.addresses["a"][0], PORT)
    joining = ["--mode", "client"] if via_router else []
    reachable = [] if via_router else ["--listen", f"{protocol}/{hosts.addresses['a'][0]}:0"]
    monitor = hosts.start("a", "monitor", *common, *joining, *reachable, "--connect", hub[0],
                          "--log", str(log), "--no-dashboard")
    robots = []
    for host, ids, endpoint in (("b", "0-2", hub[0]), ("c", "3-5", hub[1])):
        own = [] if via_router else ["--listen", f"{protocol}/{hosts.addresses[host][0]}:0"]
        robots.append(hosts.start(host, "robot", *common, *joining, *own, "--connect", endpoint, "--id", ids))
    # a hang guard only: beside a full suite and two CPU burners, retransmissions over a lossy link
    # and a loaded scheduler have taken a three-host run past 240 s
    codes = [process.wait(timeout=HANG_S) for process in (world, monitor, *robots)]
    return codes, time.monotonic() - started


@pytest.mark.parametrize(("via_router", "secure"), [(True, False), (False, False), (True, True)],
                         ids=["router", "direct", "router-secure"])
def test_a_team_over_three_hosts_converges_and_equals_the_engine(hosts: Hosts, tmp_path: Path,
                                                                  via_router: bool, secure: bool) -> None:
    team = None
    if secure:
        team = tmp_path / "team"  # every certificate valid for every host's addresses
        create_team(team, 6, hosts=(*hosts.addresses["a"], *hosts.addresses["b"], *hosts.addresses["c"]))
    codes, _ = run_team(hosts, tmp_path / "log.jsonl", via_router, secure=team)
    assert codes == [0, 0, 0, 0], hosts.errors()
    log = read_log(tmp_path / "log.jsonl")
    assert log.end["reason"] == "converged" and len(log.steps) == CONVERGED_AT
    assert log.end["consistent"] is True  # the monitor saw exactly what the senders sent
    assert_equals_engine(log)
    how = ("router" if via_router else "direct") + (", secure" if secure else "")
    print(f"three hosts ({how}): converged at step {len(log.steps)}, {log.end['wall_s']:.1f} s stepping")


@pytest.mark.skipif(shutil.which("nft") is None, reason="nftables ('nft') is not installed: apt-get install nftables")
def test_the_team_completes_when_packets_are_dropped(hosts: Hosts, tmp_path: Path) -> None:
    rules = f"""
table inet ringtrack_loss {{
    chain input {{ type filter hook input priority 0; policy accept; iifname "{hosts.devices['b'][1]}" numgen random mod 100 < 10 counter drop; }}
    chain output {{ type filter hook output priority 0; policy accept; oifname "{hosts.devices['b'][1]}" numgen random mod 100 < 10 counter drop; }}
}}
"""
    subprocess.run(["ip", "netns", "exec", hosts.names["b"], "nft", "-f", "-"], input=rules.encode(), check=True)
    steps = 100
    codes, wall = run_team(hosts, tmp_path / "log.jsonl", via_router=True, steps=steps)
    assert codes == [0, 0, 0, 0], hosts.errors()
    log = read_log(tmp_path / "log.jsonl")
    assert len(log.steps) == steps and log.end["consistent"] is True
    assert_equals_engine(log)  # TCP recovers every lost packet: the run is only slower
    counters = subprocess.run(["ip", "netns", "exec", hosts.names["b"], "nft", "-j", "list", "table", "inet",
                               "ringtrack_loss"], capture_output=True, text=True, check=True).stdout
    dropped = sum(int(part.split(",")[0]) for part in counters.split('"packets": ')[1:])
    assert dropped > 0, counters  # the loss was real
    print(f"10 % packet loss on host b's link: {dropped} packets dropped, {steps} lockstep steps in {wall:.1f} s "
          f"({log.end['wall_s']:.1f} s stepping)")
