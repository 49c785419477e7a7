"""One count of robot-to-robot traffic: step records, per-link rows, fault totals and the monitor agree.

Every robot-to-robot message a poll puts on the bus is counted once (:func:`bus.faults.request_traffic`):
the step records, the end record's per-link rows, the fault layer's ``published`` and, over Zenoh,
the monitor and the senders' own counts are one number, in the engine and in a lockstep team, with
and without faults; and a lockstep team's counts equal the engine's link by link.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from ringtrack.bus.counting import per_link, robot_link_totals, totals_by_category
from ringtrack.bus.faults import FAULT_COUNTERS
from ringtrack.tools.runlog.log import RunLog, read_log
from tests.helpers import RINGTRACK

pytestmark = [pytest.mark.processes, pytest.mark.timeout(300)]

STEPS = "300"


def run(command: str, flags: list[str], folder: Path) -> tuple[dict, RunLog]:
    """``ringtrack simulate`` or a lockstep ``ringtrack spawn`` of paper-stationary with ``flags`` (its
    monitor auditing every message itself): its summary JSON and run log."""
    summary, log = folder / f"{command}.json", folder / f"{command}.jsonl"
    extra = ["--runs", str(folder / "runs"), "--no-dashboard", "--clock", "lockstep", "--audit"] \
        if command == "spawn" else []
    completed = subprocess.run([*RINGTRACK, command, "paper-stationary", *flags, "--steps", STEPS, *extra,
                                "--json", str(summary), "--log", str(log)], capture_output=True, text=True, timeout=240)
    assert completed.returncode == 0, completed.stderr
    return json.loads(summary.read_text()), read_log(log)


def robot_links(rows: list) -> dict[tuple[str, str, str], int]:
    """Robot-to-robot messages per (kind, source, destination) of traffic rows."""
    return {link: totals["messages"] for link, totals in per_link([tuple(row) for row in rows], ("robot",)).items()}


def assert_one_count(log: RunLog) -> int:
    """The step records, the end record's per-link rows and the fault totals count the same robot-to-robot
    messages; returns that count."""
    assert log.end is not None
    stepped = sum(sum(record["sent_messages"]) for record in log.steps)
    assert stepped == sum(sum(record["received_messages"]) for record in log.steps)
    assert stepped == sum(record["traffic"]["robot"][0] for record in log.steps)
    assert stepped == sum(robot_links(log.end["traffic"]).values())
    faults = log.end["faults"]
    assert stepped == faults["published"]
    assert faults["sent"] + faults["duplicated"] == faults["delivered"] + faults["dropped"]
    return stepped


@pytest.mark.parametrize("flags", [["--drop", "0.2", "--duplicate", "0.1"], []], ids=["faults", "clean"])
def test_steps_links_faults_and_monitor_count_the_same_messages(tmp_path: Path, flags: list[str]) -> None:
    simulated, engine_log = run("simulate", flags, tmp_path)
    spawned, team_log = run("spawn", flags, tmp_path)
    count = assert_one_count(engine_log)
    assert assert_one_count(team_log) == count
    if flags:
        assert engine_log.end["faults"]["dropped"] > 0 and engine_log.end["faults"]["duplicated"] > 0
        assert count < engine_log.end["faults"]["sent"]  # requests dropped before sending were never published
    # Over Zenoh: the monitor's rows are the end record's; they equal what the senders say they sent.
    said = [row for rows in team_log.end["senders"].values() for row in rows]
    assert robot_links(said) == robot_links(team_log.end["traffic"])
    assert team_log.end["consistent"] is True
    assert spawned["messages"]["robot"] == count == totals_by_category(said)["robot"]["messages"]
    # The two runs are one: per step and robot, per link, and every fault counter.
    assert [record["sent_messages"] for record in team_log.steps] == \
        [record["sent_messages"] for record in engine_log.steps]
    assert robot_links(team_log.end["traffic"]) == robot_links(engine_log.end["traffic"])
    assert {link: totals["messages"] for link, totals in robot_link_totals(team_log.end["traffic"]).items()} == \
        {link: totals["messages"] for link, totals in robot_link_totals(engine_log.end["traffic"]).items()}
    assert {key: spawned["faults"][key] for key in FAULT_COUNTERS} == \
        {key: simulated["faults"][key] for key in FAULT_COUNTERS}
