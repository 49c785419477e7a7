"""An intruder for tests of secure teams: joins a running ``--secure`` team and, in ROUNDS
rounds 10 ms apart, publishes well-formed messages it has no right to send, following the run's
current step (a count, not a duration, so what it sends does not depend on the machine's load).

    python -m tests.intruder RUN_FOLDER ROUNDS HOW [NAME]

``HOW`` is how it joins: ``plain`` (no TLS at all, a ``tcp/`` link to the team's TLS port),
``foreign:DIR`` (the key and certificate of ``NAME`` from another authority's team folder DIR) or
``genuine`` (``NAME``'s real key and certificate from the team's folder). It then speaks as robot 3:
requests and replies to robot 4 and commands to the world (goals on the boundary), and as the world:
an End to everyone. Prints, as JSON, how many of each it sent and how many links it had.
"""

from __future__ import annotations

import json
import secrets
import sys
import time
from collections import Counter
from pathlib import Path

import zenoh

from ringtrack.bus.config import BusConfig
from ringtrack.bus.keys import BROADCAST, WORLD, Keys
from ringtrack.bus.messages import SCHEMA, Command, End, Reply, Request, encode
from ringtrack.bus.security import Security, load_team
from ringtrack.world.scenario import load_scenario

VICTIM, NEIGHBOUR = 3, 4  # it speaks as robot 3, to robot 4


def current_step(log: Path) -> int:
    """The last step the run log records (1 before the first)."""
    try:
        with log.open("rb") as file:
            file.seek(max(0, log.stat().st_size - 8192))
            tail = file.read().decode(errors="replace")
    except OSError:
        return 1
    steps = []
    for line in tail.splitlines()[1:]:  # the first may be cut by the seek
        if '"type":"step"' in line:
            try:
                steps.append(json.loads(line).get("step", 0))
            except json.JSONDecodeError:
                pass  # the line the monitor is writing now
    return max(steps, default=0) + 1


def forgeries(keys: Keys, step: int, goal: tuple[float, float]) -> dict[str, tuple[str, bytes]]:
    """What it sends each round: the key it publishes on and the payload."""
    nonce = secrets.randbits(32)
    return {
        "request": (keys.data(f"r{NEIGHBOUR}", f"r{VICTIM}", "request"),
                    encode(Request(SCHEMA, keys.run, step, VICTIM, NEIGHBOUR, nonce))),
        "reply": (keys.data(f"r{NEIGHBOUR}", f"r{VICTIM}", "reply"),
                  encode(Reply(SCHEMA, keys.run, step, VICTIM, NEIGHBOUR, nonce, goal))),
        "command": (keys.data(WORLD, f"r{VICTIM}", "command"),
                    encode(Command(SCHEMA, keys.run, step, VICTIM, goal, 0, 0.0, (0, 0), goal))),
        "end": (keys.data(BROADCAST, WORLD, "end"), encode(End(SCHEMA, keys.run, step, "done", 0.0))),
    }


def config(run: dict, how: str, name: str) -> BusConfig:
    endpoints = tuple(run["connect"])
    if how == "plain":
        return BusConfig(connect=tuple(endpoint.replace("tls/", "tcp/", 1) for endpoint in endpoints))
    folder = Path(run["secure"]) if how == "genuine" else Path(how.removeprefix("foreign:"))
    return BusConfig(listen=("tls/127.0.0.1:0",), connect=endpoints, security=Security(load_team(folder), 6))


def main(folder: Path, rounds: int, how: str, name: str = "r2") -> dict[str, object]:
    run = json.loads((folder / "run.json").read_text())
    keys = Keys(int(run["run"], 16))
    region = load_scenario(str(folder / "scenario.toml")).region
    x, y = region.point_at(1.0)  # a goal on the boundary: one the world would take
    goal = (float(x), float(y))
    sent: Counter[str] = Counter()
    bus = config(run, how, name)
    # Straight to Zenoh: the checks of open_session would refuse a foreign certificate up front.
    with zenoh.open(bus.to_zenoh(name if bus.security is not None else None)) as session:
        time.sleep(1.0)  # let gossip link it to every participant that accepts it
        links = len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))
        for _ in range(rounds):
            for what, (key, payload) in forgeries(keys, current_step(folder / "log.jsonl"), goal).items():
                session.put(key, payload)
                sent[what] += 1
            time.sleep(0.01)
        time.sleep(0.5)  # let the last round arrive before this session closes
    return {"sent": dict(sent), "links": links}


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]), int(sys.argv[2]), *sys.argv[3:])))
