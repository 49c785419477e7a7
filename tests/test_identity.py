"""One robot id, one process: a join whose id is alive is refused in one line, and a collision
that slips through is seen by both processes, whatever the clock."""

from __future__ import annotations

import asyncio
import json
import subprocess
import time
from pathlib import Path

import pytest

from ringtrack.bus.config import BusConfig, listening_locators, open_session
from ringtrack.bus.identity import IdClaim, IdCollision, refuse_if_alive
from ringtrack.bus.keys import WORLD, Keys
from ringtrack.bus.participant import Participant
from ringtrack.bus.reach import ReachTokens
from ringtrack.tools.runlog.log import read_log
from tests.helpers import RINGTRACK, assert_equals_engine, start_spawn, stop_all, wait_for_steps

JOIN_STEPS = 2000  # steps of the run an impostor joins: lockstep at 30 steps/s on a loaded machine lasts a minute


@pytest.mark.processes
@pytest.mark.timeout(360)
def test_joining_as_a_live_robot_is_refused_in_one_line(tmp_path: Path) -> None:
    """The world holds a ``reach`` token for every robot it sees alive, and a joining process asks
    for its name's as soon as it sees the world: refused whatever the load (it need not have linked
    to r3 itself), and the run goes on as if nothing happened."""
    runs = tmp_path / "runs"
    # Long enough that the run is still going when the impostor has come up on a loaded machine (a
    # robot joining a run that already ended would wait for its world).
    spawn = start_spawn(runs, "--steps", str(JOIN_STEPS))
    try:
        folder = wait_for_steps(runs, 20)
        run = json.loads((folder / "run.json").read_text())["run"]
        started = time.monotonic()
        impostor = subprocess.run([*RINGTRACK, "robot", "--join", str(folder), "--id", "3"], capture_output=True,
                                  text=True, timeout=60)
        refused_after = time.monotonic() - started
        spawn.communicate(timeout=240)
    finally:
        stop_all(spawn)
    assert impostor.returncode == 2
    assert impostor.stderr.strip().splitlines() == [
        f"ringtrack: error: r3 is already alive in run {run} (its liveliness token is up); stop that process first, "
        "or give an id no live robot has"]
    assert refused_after < 30  # refused at start, not when the run ends
    assert spawn.returncode == 0
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["id_collisions"] == 0 and summary["failures"] == {} and summary["monitor_equals_senders"] is True
    log = read_log(folder / "log.jsonl")
    assert len(log.steps) == JOIN_STEPS and all(record["live"] == list(range(6)) for record in log.steps)
    assert_equals_engine(log)  # the run is unchanged


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


def test_a_join_is_refused_on_the_worlds_word_before_it_links_to_the_live_robot() -> None:
    """Under load a joining process may see the world long before it has linked to r3 (gossip makes
    that link later): the world's ``reach`` token for r3 alone must refuse it, and a name the world
    does not see alive must pass. Here the joiner can reach nobody but the world. The world holds
    the reach tokens before its own alive token is up, as in a run, where a robot's reach token is up
    long before anyone joins as it: a joiner seeing the world's token then sees the reach tokens
    declared before it (one link delivers declarations in order)."""
    async def check(seen: set[str]) -> str | None:
        loop = asyncio.get_running_loop()
        keys = Keys(0x5EED)
        world_session = open_session(BusConfig(listen=("tcp/127.0.0.1:0",), admin_space=True))
        joiner_session = open_session(BusConfig(connect=(listening_locators(world_session)[0],)))
        world = Participant(world_session, keys, WORLD, 6, loop)
        tokens = ReachTokens(world)
        try:
            tokens.hold(seen)
            world.announce("alive")
            await refuse_if_alive(Participant(joiner_session, keys, "r3", 6, loop))
            return None
        except IdCollision as refusal:
            return str(refusal)
        finally:
            tokens.close()
            world.close()
            for session in (joiner_session, world_session):
                session.close()

    assert asyncio.run(check({"r3", "r4"})) == ("r3 is already alive in run 00005eed (its liveliness token is up); "
                                                "stop that process first, or give an id no live robot has")
    assert asyncio.run(check({"r4"})) is None
