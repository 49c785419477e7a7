"""A hostile participant for tests: joins a running team and publishes junk on its keys.

    python -m tests.hostile RUN_FOLDER SECONDS

Every round it sends each class of bad input the robots, the world and the monitor must drop and
count: bytes that are not msgpack, a message of another schema version, one of another run, robot
ids that do not exist (too large, negative), impossible values (step 0, NaN), a kind under another
kind's key, a sender its key does not name, a tick that does not fit the team, a goal off the
boundary, and a well-formed reply with a forged nonce. Prints how many of each it sent, as JSON.
"""

from __future__ import annotations

import json
import sys
import time
from collections import Counter
from pathlib import Path

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.bus.keys import Keys
from ringtrack.bus.messages import SCHEMA, Command, Reply, Request, Tick, encode

FAR_STEP = 10**9  # a step no run reaches: the monitor keeps a forged command's record pending forever


def rounds(keys: Keys, step: int) -> dict[str, tuple[str, bytes]]:
    """Each class of bad input: the key it is published on and its payload."""
    other = Keys(keys.run ^ 0xFFFF)
    request = Request(SCHEMA, keys.run, step, 0, 1, 7)
    return {
        # to robot 1
        "malformed": (keys.data("r1", "r0", "request"), b"\xc1\x00 not msgpack"),
        "schema": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA + 1, keys.run, step, 0, 1, 7))),
        "foreign": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA, other.run, step, 0, 1, 7))),
        "impossible_sender": (keys.data("r1", "r9", "request"), encode(Request(SCHEMA, keys.run, step, 9, 1, 7))),
        "negative_sender": (keys.data("r1", "r-1", "request"), encode(Request(SCHEMA, keys.run, step, -1, 1, 7))),
        "step_zero": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA, keys.run, 0, 0, 1, 7))),
        "nan_reply": (keys.data("r1", "r0", "reply"),
                      encode(Reply(SCHEMA, keys.run, step, 0, 1, 7, (float("nan"), 0.0)))),
        "route": (keys.data("r1", "r0", "reply"), encode(request)),
        "sender": (keys.data("r1", "r2", "request"), encode(request)),
        "forged_reply": (keys.data("r1", "r0", "reply"), encode(Reply(SCHEMA, keys.run, step, 0, 1, 12345, (99.0, 99.0)))),
        "far_future": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA, keys.run, 2**64 - 1, 0, 1, 7))),
        # to the world
        "world_malformed": (keys.data("world", "r3", "command"), b"\x93\x01"),
        "world_sender": (keys.data("world", "r3", "command"),
                         encode(Command(SCHEMA, keys.run, step, 4, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0)))),
        "world_off_boundary": (keys.data("world", "r3", "command"),
                               encode(Command(SCHEMA, keys.run, FAR_STEP, 3, (99.0, 99.0), 0, 0.0, (0, 0), (0.0, 0.0)))),
        # to the monitor
        "monitor_short_tick": (keys.data("monitor", "world", "tick"),
                               encode(Tick(SCHEMA, keys.run, FAR_STEP, 0.0, [(0.0, 0.0)], (0.0, 0.0), [0]))),
    }


def main(folder: Path, seconds: float) -> dict[str, int]:
    run = json.loads((folder / "run.json").read_text())
    keys = Keys(int(run["run"], 16))
    sent: Counter[str] = Counter()
    with open_session(BusConfig(connect=tuple(run["connect"]))) as session:
        time.sleep(1.0)  # let gossip link this session to every participant
        deadline = time.monotonic() + seconds
        step = 1
        while time.monotonic() < deadline:
            for name, (key, payload) in rounds(keys, step).items():
                session.put(key, payload)
                sent[name] += 1
            step += 1
            time.sleep(0.01)
        time.sleep(0.5)  # let the last round arrive before this session closes
    return dict(sent)


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]), float(sys.argv[2]))))
