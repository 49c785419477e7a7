"""A team assembled by hand around a standalone ``ringtrack router``, on loopback (no root needed):
every role is a Zenoh client of the router, as on several hosts."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from ringtrack.tools.runlog import read_log
from ringtrack.tools.supervisor import Supervisor
from tests.helpers import assert_equals_engine, processes_mentioning

pytestmark = [pytest.mark.processes, pytest.mark.timeout(180)]

ROLES = [sys.executable, "-m", "ringtrack.tools.roles"]


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
