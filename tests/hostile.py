"""A hostile participant for tests: joins a running team and publishes junk on its keys.

    python -m tests.hostile RUN_FOLDER SECONDS

Every round it sends each class of bad input the robots and the world must drop and count: bytes
that are not msgpack, a message of another schema version, one of another run, a robot id that does
not exist, a kind under another kind's key, a sender its key does not name, and a well-formed reply
with a forged nonce. Prints how many of each it sent, as JSON.
"""

from __future__ import annotations

import json
import sys
import time
from collections import Counter
from pathlib import Path

from bus.config import BusConfig, open_session
from bus.keys import Keys
from bus.messages import SCHEMA, Command, Reply, Request, encode


def main(folder: Path, seconds: float) -> dict[str, int]:
    run = json.loads((folder / "run.json").read_text())
    keys = Keys(int(run["run"], 16))
    other = Keys(keys.run ^ 0xFFFF)
    sent: Counter[str] = Counter()
    with open_session(BusConfig(connect=tuple(run["connect"]))) as session:
        time.sleep(1.0)  # let gossip link this session to every participant
        deadline = time.monotonic() + seconds
        step = 1
        while time.monotonic() < deadline:
            request = Request(SCHEMA, keys.run, step, 0, 1, 7)
            rounds = {
                "malformed": (keys.data("r1", "r0", "request"), b"\xc1\x00 not msgpack"),
                "schema": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA + 1, keys.run, step, 0, 1, 7))),
                "foreign": (keys.data("r1", "r0", "request"), encode(Request(SCHEMA, other.run, step, 0, 1, 7))),
                "impossible_sender": (keys.data("r1", "r9", "request"), encode(Request(SCHEMA, keys.run, step, 9, 1, 7))),
                "route": (keys.data("r1", "r0", "reply"), encode(request)),
                "sender": (keys.data("r1", "r2", "request"), encode(request)),
                "world_malformed": (keys.data("world", "r3", "command"), b"\x93\x01"),
                "world_sender": (keys.data("world", "r3", "command"),
                                 encode(Command(SCHEMA, keys.run, step, 4, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0)))),
                "forged_reply": (keys.data("r1", "r0", "reply"),
                                 encode(Reply(SCHEMA, keys.run, step, 0, 1, 12345, (99.0, 99.0)))),
            }
            for name, (key, payload) in rounds.items():
                session.put(key, payload)
                sent[name] += 1
            step += 1
            time.sleep(0.01)
    return dict(sent)


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1]), float(sys.argv[2]))))
