"""The launcher: robot processes forked from one preloaded process behave as started ones do."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.tools.team.supervisor import Supervisor
from tests.helpers import assert_equals_engine, command_words, processes_mentioning, scenario

pytestmark = [pytest.mark.processes, pytest.mark.timeout(180)]


def test_forked_and_started_teams_equal_the_engine_and_count_the_same_messages(tmp_path: Path) -> None:
    runs = {}
    for start in ("fork", "exec"):
        result = spawn_team(TeamPlan(scenario=scenario(max_steps=40), clock="lockstep", runs=tmp_path / start, dashboard=False,
                            start=start))
        assert result.exit_code == 0 and result.monitor_equals_senders, result
        assert (Path(result.folder) / "launcher.stderr").exists() == (start == "fork")
        log = read_log(Path(result.log))
        assert_equals_engine(log)
        runs[start] = log
    assert runs["fork"].steps == runs["exec"].steps  # the same seed: the same run, message for message


def test_a_forked_role_reports_its_own_exit_code_and_error_and_shows_its_command_line(tmp_path: Path) -> None:
    silent = ["robot", str(tmp_path / "missing.toml"), "--id", "0"]
    waiting = tmp_path / "team.toml"
    waiting.write_bytes(scenario().to_toml())
    # A robot of a run whose world never comes: it waits until it is stopped.
    patient = ["robot", str(waiting), "--run", "deadbeef", "--exit-with-parent", "--id", "1",
               "--connect", "tcp/127.0.0.1:9"]
    with Supervisor(tmp_path) as supervisor:
        bad, good = supervisor.fork([("r0", silent), ("r1", patient)])
        assert bad.process.wait(60) == 2
        assert "missing.toml" in bad.stderr_tail()
        assert b"ringtrack.tools.cli" in command_words(good.pid) and b"deadbeef" in command_words(good.pid)
        assert good.process.poll() is None
        supervisor.stop()
        assert good.process.returncode is not None and good.name in supervisor.ended
        assert supervisor.crashed() == [bad]
        good.process.send_signal(signal.SIGTERM)  # an ended child: nothing to signal, and no error
    assert supervisor.launcher is not None and supervisor.launcher.process.returncode == 0
    assert processes_mentioning(str(tmp_path)) == []


def test_the_children_of_a_launcher_whose_supervisor_died_end_on_their_own(tmp_path: Path) -> None:
    """The supervisor's end (SIGKILL included) closes the lifeline: every forked child reads end of file."""
    script = tmp_path / "supervise.py"
    waiting = tmp_path / "team.toml"
    waiting.write_bytes(scenario().to_toml())
    script.write_text(f"""
import json, sys, time
from pathlib import Path
from ringtrack.tools.team.supervisor import Supervisor
supervisor = Supervisor(Path({str(tmp_path)!r}))
children = supervisor.fork([(f"r{{i}}", ["robot", {str(waiting)!r}, "--run", "deadbeef", "--exit-with-parent",
                                         "--id", str(i), "--connect", "tcp/127.0.0.1:9"]) for i in range(3)])
print(json.dumps([child.pid for child in children]), flush=True)
time.sleep(600)
""")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, start_new_session=True)
    try:
        assert parent.stdout is not None
        pids = json.loads(parent.stdout.readline())
        assert len(pids) == 3 and all(Path(f"/proc/{pid}").exists() for pid in pids)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 30
        while processes_mentioning(str(tmp_path)) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        for pid in processes_mentioning(str(tmp_path)):
            os.kill(pid, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()
            parent.wait()
    assert processes_mentioning(str(tmp_path)) == []


@pytest.mark.processes
def test_an_estimating_robot_loads_neither_scipy_nor_filterpy() -> None:
    """What the launcher preloads plus a decentralized robot's first estimate (its filter, the region's
    inscribed circle, the fusion of two beliefs), in a fresh interpreter: no scipy, no filterpy, so a
    forked robot starts estimating at once."""
    script = (
        "import importlib, sys\n"
        "from ringtrack.tools.team.launcher import PRELOADED\n"
        "for name in PRELOADED: importlib.import_module(name)\n"
        "import numpy as np\n"
        "from ringtrack.agents.estimation import Estimator\n"
        "from ringtrack.world.scenario import load_scenario\n"
        "scenario = load_scenario('authors-moving', estimation='decentralized')\n"
        "estimator = Estimator(scenario.estimation, scenario.region, scenario.target)\n"
        "estimator.measure(scenario.start_positions(0)[:1], [3.0])\n"
        "estimator.fuse((np.array([4.0, 19.0]), np.eye(2)), (np.array([4.5, 20.0]), 2 * np.eye(2)))\n"
        "scenario.region.chebyshev_centre\n"
        "print(sorted({name.split('.')[0] for name in sys.modules} & {'scipy', 'filterpy'}))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
