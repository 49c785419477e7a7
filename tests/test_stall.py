"""The stall guard counts from the first step, start-up has a bound of its own, and both say what the run
waited for."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from ringtrack.tools.team.spawn import stalled_at
from ringtrack.tools.team.supervisor import Supervisor


@pytest.mark.processes
def test_a_long_start_up_is_not_a_stall(tmp_path: Path) -> None:
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("slow", [sys.executable, "-c", "import time; time.sleep(1.5)"])
        started = time.monotonic()
        supervisor.wait(stall_s=0.3, watched=tmp_path / "log.jsonl", started=lambda: False)
        assert time.monotonic() - started > 1.0  # waited for the child, raised nothing


@pytest.mark.processes
def test_a_run_that_stops_growing_after_its_first_step_is_a_stall(tmp_path: Path) -> None:
    log = tmp_path / "log.jsonl"
    log.write_text("{}\n")
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("hung", [sys.executable, "-c", "import time; time.sleep(30)"])
        with pytest.raises(TimeoutError) as raised:
            supervisor.wait(stall_s=0.3, watched=log, started=lambda: True)
    assert str(raised.value) == f"{log} did not grow for 0.3 s"


@pytest.mark.processes
def test_a_start_up_that_never_ends_is_bounded(tmp_path: Path) -> None:
    """A participant that never comes up (a Zenoh declaration that deadlocks, seen once) must not
    hold spawn for ever: past the start-up bound the wait ends, saying so; a long start-up within it
    is waited out (above)."""
    from ringtrack.tools.team.spawn import STALL_TIMEOUT_S, startup_limit

    assert startup_limit(64) > startup_limit(8) > STALL_TIMEOUT_S  # a larger team may take longer
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("hung", [sys.executable, "-c", "import time; time.sleep(30)"])
        with pytest.raises(TimeoutError) as raised:
            supervisor.wait(stall_s=60.0, watched=tmp_path / "log.jsonl", started=lambda: False, startup_s=0.3)
    assert str(raised.value) == "the team did not reach its first step within 0.3 s of start-up"


def test_a_stall_says_which_step_and_which_robot_it_waited_for(tmp_path: Path) -> None:
    (tmp_path / "world.stderr").write_text("ringtrack.world: lockstep step 7 waits for r3\n")
    expected = "after step 0 (waiting for step 1; lockstep step 7 waits for r3)"
    assert stalled_at(tmp_path / "log.jsonl", tmp_path) == expected


@pytest.mark.processes
def test_a_log_that_appears_and_vanishes_is_waited_through(tmp_path: Path) -> None:
    """The monitor's ``--log`` check makes the log and removes it again before the monitor writes it
    for good: the stall guard, polling beside it, must take a log gone between two looks as empty."""
    log = tmp_path / "log.jsonl"
    probe = f"import pathlib, time\nend = time.monotonic() + 1.5\nlog = pathlib.Path({str(log)!r})\n" \
            "while time.monotonic() < end:\n    log.open('xb').close()\n    log.unlink()\n"
    with Supervisor(tmp_path) as supervisor:
        supervisor.start("probe", [sys.executable, "-c", probe])
        supervisor.wait(stall_s=60.0, watched=log, started=lambda: True, poll_s=0.001)
    assert supervisor.children[0].process.returncode == 0
