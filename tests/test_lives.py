"""Fenced lives: the world grants every process of a robot id a life number; a process frozen past
the lease, whose id a new process then took, stops with code 2 and one line as soon as it learns of
the newer life, and the run's books (every life of every sender against the monitor's wire audit)
balance.

The split-brain probe: freeze r3 with SIGSTOP until the world has dropped it, start a new r3
(``robot --join``), then wake the old one."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from ringtrack.bus.config import BusConfig, listening_locators, open_session
from ringtrack.bus.counting import close_books
from ringtrack.bus.identity import IdClaim
from ringtrack.bus.keys import WORLD, Keys
from ringtrack.bus.lives import CURRENT, LifeRegistry, NewerLife, ask_life
from ringtrack.bus.participant import Participant
from ringtrack.tools.runlog.log import read_log
from tests.helpers import RINGTRACK, processes_mentioning, start_spawn, stop_all, wait_for_steps
from tests.test_centre import _robot_pid
from tests.test_freeze import dropped

KEYS = Keys(0x5EED)


def test_the_world_grants_each_life_of_a_name_the_next_number_and_tells_the_newest() -> None:
    async def grants() -> tuple[list[int], int, int, dict[str, int]]:
        loop = asyncio.get_running_loop()
        world_session = open_session(BusConfig(listen=("tcp/127.0.0.1:0",), admin_space=True))
        robot_session = open_session(BusConfig(connect=(listening_locators(world_session)[0],)))
        world = Participant(world_session, KEYS, WORLD, 6, loop)
        registry = LifeRegistry(world)
        try:
            robot = Participant(robot_session, KEYS, "r3", 6, loop)
            lives = [await ask_life(robot) for _ in range(3)]
            newest = int(next(iter(robot_session.get(f"{KEYS.life('r3')}?{CURRENT}", timeout=2.0))).ok.payload
                         .to_bytes())
            other = await ask_life(Participant(robot_session, KEYS, "r4", 6, loop))
            return lives, newest, other, dict(world.lives)
        finally:
            registry.close()
            for session in (robot_session, world_session):
                session.close()

    lives, newest, other, door = asyncio.run(grants())
    assert lives == [1, 2, 3]
    assert newest == 3  # asking for the newest takes no life
    assert other == 1  # every name counts its own lives
    assert door == {"r3": 3, "r4": 1}  # the world's door refuses older lives from the first grant on


def test_a_claim_by_a_newer_life_tells_the_older_one_and_a_claim_by_the_same_life_is_a_collision() -> None:
    async def claims() -> tuple[list[object], set[str], int, list[object]]:
        loop = asyncio.get_running_loop()
        hub = open_session(BusConfig(listen=("tcp/127.0.0.1:0",), admin_space=True))
        config = BusConfig(listen=("tcp/127.0.0.1:0",), connect=(listening_locators(hub)[0],))
        sessions = [open_session(config) for _ in range(3)]
        participants = [Participant(session, KEYS, "r3", 6, loop) for session in sessions]
        for participant, life in zip(participants, (1, 2, 1), strict=True):
            participant.live_as(life)
        try:
            old, new, twin = (IdClaim(participant) for participant in participants)
            deadline = time.monotonic() + 10
            while not (old.newer and twin.newer and old.rivals) and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            for claim in (old, new, twin):
                claim.close()
            return (participants[0].inbox.take(), old.rivals, new.newer,
                    [item for item in participants[1].inbox.take() if isinstance(item, NewerLife)])
        finally:
            for session in (*sessions, hub):
                session.close()

    told, rivals, newest_seen_by_new, told_new = asyncio.run(claims())
    assert told == [NewerLife(2)]  # once, however many claims of life 2 it sees
    assert len(rivals) == 1  # the other life-1 session: a collision no fence can settle
    assert newest_seen_by_new == 0 and told_new == []  # older lives never disturb the newest


def test_books_balance_link_by_link_and_name_what_was_in_flight_when_a_process_was_cut_off() -> None:
    said = [("request", "r3", "r2", 10, 160), ("command", "r3", "world", 50, 4000), ("reply", "r1", "r2", 7, 70),
            ("command", "r1", "world", 50, 4000)]
    seen = [("request", "r3", "r2", 9, 144), ("command", "r3", "world", 50, 4000), ("reply", "r1", "r2", 6, 60),
            ("command", "r1", "world", 51, 4080)]
    books = close_books(said, seen, cut_off={"r3"}, categories=("robot", "world"))
    assert books.in_flight == {("request", "r3", "r2"): 1}
    assert books.unexplained == {("command", "r1", "world"): (50, 51), ("reply", "r1", "r2"): (7, 6)}
    assert not books.balanced
    assert books.lines() == [
        "request r3 > r2: 1 in flight when the link closed (a process was cut off)",
        "command r1 > world: 50 sent, 51 seen (unexplained)",
        "reply r1 > r2: 7 sent, 6 seen (unexplained)"]
    assert close_books(said[:2], seen[:2], cut_off={"r3"}, categories=("robot", "world")).balanced
    # a sender one of whose lives left no books: its messages are compared, their bytes cannot be
    assert close_books(said, [seen[0], seen[1], ("reply", "r1", "r2", 7, 90), said[3]], cut_off={"r3"},
                       categories=("robot", "world"), silent=frozenset({"r1"})).balanced
    assert not close_books(said, [seen[0], seen[1], ("reply", "r1", "r2", 7, 90), said[3]], cut_off={"r3"},
                           categories=("robot", "world")).balanced


def split_brain(runs: Path, *arguments: str) -> tuple[Path, float, int, dict, str]:
    """Freeze r3 until the world drops it, start a new r3 in its place, wake the old one; returns the
    run folder, the seconds from the old life's waking to its end, spawn's exit code, the summary
    and the new r3's standard error. Every process is ended, also on failure."""
    spawn = start_spawn(runs, "--lease", "2", *arguments)
    old = None
    new: subprocess.Popen[str] | None = None
    try:
        folder = wait_for_steps(runs, 50, timeout_s=90)
        old = _robot_pid(folder, 3)
        os.kill(old, signal.SIGSTOP)
        deadline = time.monotonic() + 60
        while not dropped(folder) and time.monotonic() < deadline:
            time.sleep(0.05)
        new = subprocess.Popen([*RINGTRACK, "robot", "--join", str(folder), "--id", "3"], stderr=subprocess.PIPE,
                               text=True)
        deadline = time.monotonic() + 60
        while "r3 joins as life 2" not in (folder / "world.stderr").read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(old, signal.SIGCONT)
        woke = time.monotonic()
        while old in processes_mentioning(str(folder)) and time.monotonic() - woke < 60:
            time.sleep(0.02)
        ended_after = time.monotonic() - woke
        spawn.communicate(timeout=240)
        _, new_stderr = new.communicate(timeout=60)
    finally:
        if old is not None:
            try:
                os.kill(old, signal.SIGCONT)
            except ProcessLookupError:
                pass
        stop_all(spawn)
        if new is not None and new.poll() is None:
            new.kill()
            new.wait()
    return folder, ended_after, spawn.returncode, json.loads((folder / "summary.json").read_text()), new_stderr


def assert_fenced(folder: Path, ended_after: float, code: int, summary: dict, new_stderr: str) -> None:
    """The old life stopped with the one line; spawn excused its exit code 2 (a fenced life) and
    nothing else failed; both lives' books reached the monitor and balance."""
    run = summary["run"]
    assert (folder / "r3.stderr").read_text().strip().splitlines()[-1] == (
        f"ringtrack: error: r3 (life 1) of run {run} was replaced by life 2 of r3 (it was seen gone and its id "
        "rejoined); this process stops")
    assert ended_after < 30, ended_after  # a hang guard; the time is reported, not bounded
    assert code == 0 and summary["failures"] == {} and summary["distrust"] is None, summary
    assert summary["fenced_lives"] == 1 and summary["id_collisions"] == 0
    assert new_stderr.strip() == ""  # the new life ran to the end
    end = read_log(folder / "log.jsonl").end
    assert end is not None and end["consistent"] is True, end["books"]
    assert {"r3", "r3.life2"} <= end["senders"].keys()  # both lives' books reached the monitor
    assert re.search(r"r3 joins as life 2 of r3", (folder / "world.stderr").read_text())
    print(f"old life ended {ended_after:.2f} s after waking; books: {end['books'] or 'equal on every link'}; "
          f"rejected: {end['rejected']}")


@pytest.mark.processes
@pytest.mark.timeout(400)
def test_split_brain_in_lockstep_fences_the_old_life_and_the_audited_books_balance(tmp_path: Path) -> None:
    assert_fenced(*split_brain(tmp_path / "runs", "--steps", "2500", "--audit"))


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(400)
def test_split_brain_in_realtime_fences_the_old_life_and_the_books_balance(tmp_path: Path) -> None:
    assert_fenced(*split_brain(tmp_path / "runs", "--clock", "realtime", "--rate", "5", "--steps", "700"))
