"""One robot id, one process: a join whose id is alive is refused in one line, and a collision
that slips through is seen by both processes, whatever the clock."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from ringtrack.bus.config import BusConfig, listening_locators, open_session
from ringtrack.bus.identity import IdClaim
from ringtrack.bus.keys import Keys
from ringtrack.bus.participant import Participant
from tests.helpers import RINGTRACK, start_spawn, stop_all, wait_for_steps


@pytest.mark.processes
@pytest.mark.xfail(strict=False, reason="known: under heavy load the joining robot may link to r3 only after its "
                   "liveliness check settled (1 s after seeing the world) and is then let in; the collision is still "
                   "detected by the claim tokens (warning), see the test below")
def test_joining_as_a_live_robot_is_refused_in_one_line(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    spawn = start_spawn(runs, "--steps", "3000")
    try:
        folder = wait_for_steps(runs, 20)
        run = (folder / "run.json").read_text().split('"run": "')[1][:8]
        started = time.monotonic()
        impostor = subprocess.run([*RINGTRACK, "robot", "--join", str(folder), "--id", "3"], capture_output=True,
                                  text=True, timeout=60)
        refused_after = time.monotonic() - started
        os.kill(spawn.pid, signal.SIGTERM)
        spawn.communicate(timeout=30)
    finally:
        stop_all(spawn)
    assert impostor.returncode == 2
    assert impostor.stderr.strip().splitlines() == [
        f"ringtrack: error: r3 is already alive in run {run} (its liveliness token is up); stop that process first, "
        "or give an id no live robot has"]
    assert refused_after < 30  # refused at start, not when the run ends


def test_an_id_collision_is_seen_by_both_processes(tmp_path: Path) -> None:
    async def collide() -> tuple[set[str], set[str], str, str]:
        loop = asyncio.get_running_loop()
        keys = Keys(0x5EED)
        hub = open_session(BusConfig(listen=("tcp/127.0.0.1:0",), admin_space=True))
        config = BusConfig(listen=("tcp/127.0.0.1:0",), connect=(listening_locators(hub)[0],))
        sessions = [open_session(config), open_session(config)]
        try:
            first, second = (IdClaim(Participant(session, keys, "r3", 6, loop)) for session in sessions)
            deadline = time.monotonic() + 10
            while not (first.rivals and second.rivals) and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            first.close()
            second.close()
            return first.rivals, second.rivals, first.zid, second.zid
        finally:
            for session in (*sessions, hub):
                session.close()

    first_rivals, second_rivals, first_zid, second_zid = asyncio.run(collide())
    assert first_rivals == {second_zid}
    assert second_rivals == {first_zid}
