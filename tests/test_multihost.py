"""A team spread over three hosts: network namespaces joined by veth links (root only).

Host A runs the world, as the Zenoh router, and the monitor; hosts B and C run three robots each,
packed into one process per host, as Zenoh clients of the router. Robot-to-robot traffic between
B and C crosses A. The lockstep run must equal the engine, and still complete when nftables drops
a share of the packets on B's link (TCP retransmits: loss becomes delay).
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

from tests.emulation import assert_equals_engine
from tools.runlog import read_log

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root"),
    pytest.mark.skipif(shutil.which("ip") is None, reason="iproute2 ('ip') is not installed"),
]

RUN = "5eed0042"
STEPS = 200
PORT = 7447


def sh(*command: str) -> None:
    subprocess.run(command, check=True, capture_output=True)


class Hosts:
    """Namespaces ``a``, ``b``, ``c``; b and c each linked to a by a veth pair (10.77.1.0/24, 10.77.2.0/24)."""

    def __init__(self) -> None:
        tag = f"{os.getpid() % 100000}"
        self.names = {host: f"rt{host}{tag}" for host in "abc"}
        self.addresses = {"b": ("10.77.1.1", "10.77.1.2"), "c": ("10.77.2.1", "10.77.2.2")}
        self.devices = {host: (f"va{host}{tag}", f"v{host}a{tag}") for host in "bc"}
        for name in self.names.values():
            sh("ip", "netns", "add", name)
            sh("ip", "-n", name, "link", "set", "lo", "up")
        for host in "bc":
            outer, inner = self.devices[host]
            sh("ip", "link", "add", outer, "type", "veth", "peer", "name", inner)
            sh("ip", "link", "set", outer, "netns", self.names["a"])
            sh("ip", "link", "set", inner, "netns", self.names[host])
            router_ip, host_ip = self.addresses[host]
            sh("ip", "-n", self.names["a"], "addr", "add", f"{router_ip}/24", "dev", outer)
            sh("ip", "-n", self.names[host], "addr", "add", f"{host_ip}/24", "dev", inner)
            sh("ip", "-n", self.names["a"], "link", "set", outer, "up")
            sh("ip", "-n", self.names[host], "link", "set", inner, "up")
        self.processes: list[subprocess.Popen[bytes]] = []

    def start(self, host: str, *arguments: str) -> subprocess.Popen[bytes]:
        command = ["ip", "netns", "exec", self.names[host], sys.executable, "-m", "tools.roles"]
        process = subprocess.Popen([*command, *arguments], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                   cwd=Path(__file__).parents[1])
        self.processes.append(process)
        return process

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


def run_team(hosts: Hosts, log: Path) -> tuple[list[int], float]:
    """World (router) and monitor on a, robots 0-2 on b and 3-5 on c; returns exit codes and wall time."""
    common = ["paper-stationary", "--run", RUN, "--steps", str(STEPS), "--monitor"]
    world_endpoints = [flag for host in "bc" for flag in ("--listen", f"tcp/{hosts.addresses[host][0]}:{PORT}")]
    started = time.monotonic()
    world = hosts.start("a", "world", *common, "--mode", "router", "--listen", f"tcp/127.0.0.1:{PORT}", *world_endpoints)
    time.sleep(1.0)
    monitor = hosts.start("a", "monitor", *common, "--mode", "client", "--connect", f"tcp/127.0.0.1:{PORT}",
                          "--log", str(log), "--no-dashboard")
    robots = [hosts.start(host, "robot", *common, "--mode", "client", "--connect",
                          f"tcp/{hosts.addresses[host][0]}:{PORT}", "--id", ids) for host, ids in (("b", "0-2"), ("c", "3-5"))]
    codes = [process.wait(timeout=240) for process in (world, monitor, *robots)]
    return codes, time.monotonic() - started


def test_a_team_over_three_hosts_equals_the_engine(hosts: Hosts, tmp_path: Path) -> None:
    codes, _ = run_team(hosts, tmp_path / "log.jsonl")
    assert codes == [0, 0, 0, 0], [process.stderr.read().decode()[-500:] for process in hosts.processes]
    log = read_log(tmp_path / "log.jsonl")
    assert len(log.steps) == STEPS and log.end["consistent"] is True
    assert_equals_engine(log)
    print(f"three hosts, no loss: {STEPS} lockstep steps, {log.end['wall_s']:.1f} s stepping")


@pytest.mark.skipif(shutil.which("nft") is None, reason="nftables ('nft') is not installed: apt-get install nftables")
def test_the_team_completes_when_packets_are_dropped(hosts: Hosts, tmp_path: Path) -> None:
    rules = f"""
table inet ringtrack_loss {{
    chain input {{ type filter hook input priority 0; policy accept; iifname "{hosts.devices['b'][1]}" numgen random mod 100 < 10 counter drop; }}
    chain output {{ type filter hook output priority 0; policy accept; oifname "{hosts.devices['b'][1]}" numgen random mod 100 < 10 counter drop; }}
}}
"""
    subprocess.run(["ip", "netns", "exec", hosts.names["b"], "nft", "-f", "-"], input=rules.encode(), check=True)
    codes, wall = run_team(hosts, tmp_path / "log.jsonl")
    assert codes == [0, 0, 0, 0], [process.stderr.read().decode()[-500:] for process in hosts.processes]
    log = read_log(tmp_path / "log.jsonl")
    assert len(log.steps) == STEPS
    assert_equals_engine(log)  # TCP recovers every lost packet: the run is only slower
    counters = subprocess.run(["ip", "netns", "exec", hosts.names["b"], "nft", "list", "table", "inet", "ringtrack_loss"],
                              capture_output=True, text=True, check=True).stdout
    print(f"10 % packet loss on host b's link: {STEPS} lockstep steps in {wall:.1f} s "
          f"({log.end['wall_s']:.1f} s stepping)\n{counters}")
