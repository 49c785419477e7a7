"""The nemesis: plans parsed with one-line errors, carried out against live six-robot teams with the
wire audit on (books balance, no two processes act as one life), and a lost monitor noticed by the
team itself."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from ringtrack.bus.lives import SUPERSEDED_MARK
from ringtrack.tools.output.console import UsageError
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.studies.nemesis import fenced_after_s
from ringtrack.tools.team.nemesis import (
    EXAMPLE,
    MONITOR_RETURN_S,
    Fault,
    monitor_grace_s,
    parse_plan,
    random_plan,
    split_brain,
)
from tests.helpers import RINGTRACK, processes_mentioning


def test_a_plan_reads_as_faults_in_time_order() -> None:
    assert parse_plan("kill r3@5s, restart r3@8s, pause r1@1.5s:3s, partition r0-r2@12s:4s, kill monitor@15s",
                      6) == [Fault("pause", "r1", 1.5, 3.0), Fault("kill", "r3", 5.0), Fault("restart", "r3", 8.0),
                             Fault("partition", "r0-r2", 12.0, 4.0), Fault("kill", "monitor", 15.0)]
    assert str(Fault("pause", "r1", 1.5, 3.0)) == "pause r1@1.5s:3s"


def test_a_plan_file_holds_its_faults_in_a_nemesis_table(tmp_path: Path) -> None:
    path = tmp_path / "plan.toml"
    path.write_text('[nemesis]\nfaults = ["kill r2@1s", "restart r2@2s"]\n')
    assert parse_plan(str(path), 6) == [Fault("kill", "r2", 1.0), Fault("restart", "r2", 2.0)]
    path.write_text("[nemesis]\nfaults = 3\n")
    with pytest.raises(UsageError, match=r"faults must be a list of strings like \"kill r3@5s\""):
        parse_plan(str(path), 6)


@pytest.mark.parametrize(("plan", "error"), [
    ("kill r9@5s", "--nemesis 'kill r9@5s': the team has robots r0..r5"),
    ("explode r1@5s", "--nemesis 'explode r1@5s': unknown action 'explode'; use kill, restart, pause or partition"),
    ("pause r1@5s", "--nemesis 'pause r1@5s': a pause needs its length (pause r1@10s:3s), and only a pause or a "
                    "partition has one"),
    ("partition r1-r1@5s:1s", "--nemesis 'partition r1-r1@5s:1s': a partition cuts the link of two robots: "
                              "partition r0-r2@12s:4s"),
    ("partition r1-r7@5s:1s", "--nemesis 'partition r1-r7@5s:1s': the team has robots r0..r5"),
    ("partition r1-r2@5s", "--nemesis 'partition r1-r2@5s': a partition needs its length (partition r0-r2@12s:4s)"),
    ("restart world@5s", "--nemesis 'restart world@5s': only a robot or the monitor can be restarted"),
    ("restart monitor@5s", "--nemesis 'restart monitor@5s': a monitor is restarted after it was killed: kill "
                           "monitor@3s, restart monitor@5s"),
    ("kill monitor@1s, restart monitor@3s, restart monitor@5s", "--nemesis 'restart monitor@5s': a monitor is "
     "restarted after it was killed: kill monitor@3s, restart monitor@5s"),
    ("kill fusion@5s", "--nemesis 'kill fusion@5s': 'fusion' is no participant; name r0..r5, monitor or world"),
    ("kill r1 at 5", f"--nemesis 'kill r1 at 5': write a fault like 'kill r3@5s' or 'pause r1@10s:3s' (e.g. "
                     f"{EXAMPLE})"),
    (" , ", f"--nemesis ' , ': no fault in it; e.g. {EXAMPLE}"),
])
def test_a_bad_plan_gets_one_line_naming_the_fault_and_the_fix(plan: str, error: str) -> None:
    with pytest.raises(UsageError) as raised:
        parse_plan(plan, 6)
    assert str(raised.value) == error


def test_random_plans_are_seeded_and_restart_every_robot_they_kill() -> None:
    plan = random_plan(7, 6, 10.0, faults=6)
    assert plan == random_plan(7, 6, 10.0, faults=6) and plan != random_plan(8, 6, 10.0, faults=6)
    assert [fault.at_s for fault in plan] == sorted(fault.at_s for fault in plan)
    kills = [fault for fault in plan if fault.action == "kill"]
    for kill in kills:
        assert any(fault.action == "restart" and fault.target == kill.target and fault.at_s >= kill.at_s
                   for fault in plan)
    assert all(fault.for_s is not None and fault.for_s > 0 for fault in plan if fault.action == "pause")
    assert all(fault.at_s + (fault.for_s or 0.0) <= 10.0 for fault in plan)  # every fault over within the span
    assert len({fault.target.split("-")[0] for fault in plan}) == 6  # one robot, one kind of fault
    links = [fault.target.split("-") for fault in plan if fault.action == "partition"]
    assert all(int(b[1:]) == (int(a[1:]) + 1) % 6 for a, b in links)  # a ring link


def test_the_world_holds_for_a_restarted_monitor_its_longest_absence_and_a_start_up() -> None:
    plan = parse_plan("kill monitor@1s, restart monitor@3s, kill monitor@10s, restart monitor@16s", 6)
    assert monitor_grace_s(plan) == 6.0 + MONITOR_RETURN_S
    assert monitor_grace_s(parse_plan("kill monitor@1s, restart r3@3s", 6)) is None


def test_a_fenced_life_is_timed_from_its_waking_to_the_line_that_says_it_stops(tmp_path: Path) -> None:
    (tmp_path / "r3.stderr").write_text(f"ringtrack: error: r3 (life 1) of run 1 {SUPERSEDED_MARK} 2 of r3\n")
    (tmp_path / "r3@1.stderr").write_text("")
    (tmp_path / "r1.stderr").write_text(f"{SUPERSEDED_MARK}\n")  # never woken by the nemesis: not timed
    os.utime(tmp_path / "r3.stderr", (1000.0, 1001.25))
    struck = [{"fault": "pause r3@1s:6s", "wall": 990.0}, {"fault": "wake r3", "wall": 1000.0}]
    assert fenced_after_s(tmp_path, struck) == [1.25]


def test_a_split_brain_restarts_a_robot_frozen_past_the_lease_before_waking_it() -> None:
    assert split_brain("r3", 1.0, 2.0) == [Fault("pause", "r3", 1.0, 6.0), Fault("restart", "r3", 4.0)]


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(600)
def test_the_nemesis_against_lockstep_and_realtime_teams_leaves_balanced_books_and_no_overlapping_lives(
        tmp_path: Path) -> None:
    done = subprocess.run([*RINGTRACK, "experiment", "nemesis", "--schedules", "2", "--steps", "500", "--seed", "3",
                           "--runs", str(tmp_path / "runs"), "--json", str(tmp_path / "nemesis.json"), "--quiet"],
                          capture_output=True, text=True, timeout=560)
    assert done.returncode == 0, done.stdout + done.stderr
    study = json.loads((tmp_path / "nemesis.json").read_text())
    assert [row["clock"] for row in study["rows"]] == ["lockstep", "realtime"]
    assert study["overlapping_lives"] == 0 and study["unbalanced_books"] == 0
    for row, folder in zip(study["rows"], sorted((tmp_path / "runs").iterdir()), strict=True):
        carried_out = [json.loads(line)["fault"] for line in (folder / "nemesis.jsonl").read_text().splitlines()]
        planned = row["plan"].split(", ")
        struck = [fault for fault in carried_out if not fault.startswith(("wake ", "heal "))]
        assert struck == planned[:len(struck)] and len(struck) >= len(planned) / 2  # none once the run was over
        for begun, ended in (("pause ", "wake "), ("partition ", "heal ")):  # each ended, in time or as the run did
            lasting = sorted(fault.split("@")[0].removeprefix(begun) for fault in struck if fault.startswith(begun))
            assert sorted(fault.removeprefix(ended) for fault in carried_out if fault.startswith(ended)) == lasting
        summary = json.loads((folder / "summary.json").read_text())
        end = read_log(folder / "log.jsonl").end
        assert end is not None and end["consistent"] is True and summary["distrust"] is None, end["books"]
        assert summary["id_collisions"] == 0 and summary["exit_code"] == 0 and row["reformed"]
    assert processes_mentioning(str(tmp_path)) == []


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_a_killed_monitor_is_noticed_by_the_world_which_ends_the_run_in_one_line(tmp_path: Path) -> None:
    done = subprocess.run([*RINGTRACK, "spawn", "paper-stationary", "--robots", "6", "--steps", "100000",
                           "--runs", str(tmp_path), "--no-dashboard", "--nemesis", "kill monitor@1s"],
                          capture_output=True, text=True, timeout=240)
    (folder,) = tmp_path.iterdir()
    world = (folder / "world.stderr").read_text()
    assert done.returncode == 1
    assert "the monitor went away at step" in world and "nobody keeps the run's log and books; ending the run" in world
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["stopped"] is None  # the team ended on its own: spawn did not have to stop it
    assert summary["failures"] == {"world": 1} and summary["monitor_lost"] is True
    assert [json.loads(line)["fault"] for line in (folder / "nemesis.jsonl").read_text().splitlines()] == [
        "kill monitor@1s"]
    assert processes_mentioning(str(folder)) == []


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(300)
def test_a_partition_cuts_a_ring_link_for_its_time_and_every_message_across_it_is_counted(tmp_path: Path) -> None:
    done = subprocess.run([*RINGTRACK, "spawn", "authors-moving", "--clock", "realtime", "--rate", "5", "--steps", "400",
                           "--lease", "2", "--audit", "--no-dashboard", "--runs", str(tmp_path),
                           "--nemesis", "partition r0-r1@1s:3s"], capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    (folder,) = tmp_path.iterdir()
    struck = [json.loads(line) for line in (folder / "nemesis.jsonl").read_text().splitlines()]
    assert [entry["fault"] for entry in struck] == ["partition r0-r1@1s:3s", "heal r0-r1"]
    log = read_log(folder / "log.jsonl")
    outages = [event for event in log.events if event["event"] == "dropped" and event["reason"] == "outage"]
    assert outages and all({event["sender"], event["receiver"]} == {0, 1} for event in outages)
    faults = log.end["faults"]
    assert faults["sent"] + faults["duplicated"] == faults["delivered"] + faults["dropped"]
    assert faults["dropped"] == len(outages)
    assert log.end["consistent"] is True
    # the link works again once healed: r0 and r1 poll each other after the partition's last drop
    healed = max(event["step"] for event in outages)
    assert any(link[1:3] in ([0, 1], [1, 0]) for record in log.steps[healed:] for link in record["links"])
