"""A team assembled by hand around a standalone ``ringtrack router``, on loopback (no root needed):
every role is a Zenoh client of the router, as on several hosts."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest
import zenoh

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.supervisor import Supervisor
from tests.helpers import assert_equals_engine, processes_mentioning

pytestmark = [pytest.mark.processes, pytest.mark.timeout(180)]

ROLES = [sys.executable, "-m", "ringtrack.tools.cli"]


def test_a_team_through_a_standalone_router_equals_the_engine(tmp_path: Path) -> None:
    run = "0dd5eed5"
    common = ["paper-stationary", "--run", run, "--steps", "300", "--monitor", "--exit-with-parent"]
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("router", [*ROLES, "router", "--listen", "tcp/127.0.0.1:0",
                                    "--announce", str(tmp_path / "router.json"), "--exit-with-parent"])
        (endpoint,) = supervisor.endpoints(tmp_path / "router.json", "router")
        client = ["--mode", "client", "--connect", endpoint]
        supervisor.start("world", [*ROLES, "world", *common, *client])
        supervisor.start("monitor", [*ROLES, "monitor", *common, *client, "--log", str(tmp_path / "log.jsonl"),
                                     "--no-dashboard"])
        for ids in ("0-2", "3-5"):
            supervisor.start(f"r{ids}", [*ROLES, "robot", *common, *client, "--id", ids])
        team = [child for child in supervisor.children if child.name != "router"]
        for child in team:
            assert child.process.wait(timeout=120) == 0, child.stderr_tail()
        assert supervisor.children[0].process.poll() is None  # the router serves on until stopped
    assert not processes_mentioning(run)
    log = read_log(tmp_path / "log.jsonl")
    assert len(log.steps) == 300 and log.end["consistent"] is True
    assert_equals_engine(log)


def test_a_burst_through_a_router_arrives_whole(tmp_path: Path) -> None:
    """A router forwarding a burst larger than a link's transmit queue (2 batches of 64 KiB) delivers
    all of it. On a single Zenoh thread it stalled until Zenoh closed the link (5 s), losing what was
    queued: 94 of 2000 arrived."""
    burst, size = 2000, 1000
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("router", [*ROLES, "router", "--listen", "tcp/127.0.0.1:0",
                                    "--announce", str(tmp_path / "router.json"), "--exit-with-parent"])
        (endpoint,) = supervisor.endpoints(tmp_path / "router.json", "router")
        client = BusConfig(mode="client", listen=(), connect=(endpoint,))
        with open_session(client) as receiving, open_session(client) as sending:
            subscriber = receiving.declare_subscriber("burst/**", zenoh.handlers.FifoChannel(2 * burst))
            publisher = sending.declare_publisher("burst/data", congestion_control=zenoh.CongestionControl.BLOCK)
            deadline = time.monotonic() + 30  # a hang guard: nothing here is timed
            while not publisher.matching_status.matching and time.monotonic() < deadline:
                time.sleep(0.01)
            for _ in range(burst):
                publisher.put(bytes(size))
            received = 0
            while received < burst and time.monotonic() < deadline:
                if subscriber.try_recv() is None:
                    time.sleep(0.001)
                else:
                    received += 1
            publisher.undeclare()
            subscriber.undeclare()
    assert received == burst
