"""Hostile traffic must not grow memory or lie: bounded buffers per claimed step, answers a flood
can draw, payloads longer than their kind, and a forged End that empties the ring."""

from __future__ import annotations

import json
import time
from pathlib import Path

import msgspec
import pytest

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.bus.keys import BROADCAST, WORLD, Keys, Route
from ringtrack.bus.messages import SCHEMA, End, Rejected, Reply, Request, decode, encode
from ringtrack.bus.participant import Delivery
from ringtrack.tools.monitor.monitor import AHEAD_STEPS, PENDING_LIMIT, Recorder
from ringtrack.tools.runlog.log import LogWriter
from tests.helpers import processes_mentioning, scenario, start_spawn, stop_all, wait_for_steps
from tests.test_node import RUN, make_node

REPLY_ROUTE = Route("r1", "r0", "reply")


def test_a_reply_with_trailing_fields_is_refused_for_its_size() -> None:
    reply = Reply(SCHEMA, RUN, 3, 0, 1, 7, (1.0, 2.0))
    padded = msgspec.msgpack.encode([*msgspec.msgpack.decode(encode(reply)), "x" * 100])
    assert decode(encode(reply), REPLY_ROUTE, RUN, 6) == reply
    with pytest.raises(Rejected) as trailing:
        decode(padded, REPLY_ROUTE, RUN, 6)
    assert trailing.value.reason == "size"
    huge = msgspec.msgpack.encode([*msgspec.msgpack.decode(encode(reply)), b"\0" * 2**20])
    started = time.perf_counter()
    with pytest.raises(Rejected) as oversize:
        decode(huge, REPLY_ROUTE, RUN, 6)
    assert oversize.value.reason == "size"
    assert str(oversize.value) == f"size: {len(huge)} bytes on {REPLY_ROUTE}, more than a reply can be"
    assert time.perf_counter() - started < 0.01  # refused before decoding


def test_forged_far_future_steps_do_not_grow_the_monitor(tmp_path: Path) -> None:
    with LogWriter(tmp_path / "log.jsonl") as writer:
        recorder = Recorder(writer, scenario())
        forged = 20_000
        for index in range(forged):
            request = Request(SCHEMA, RUN, 10**6 + index, 0, 1, 7)
            recorder.on_delivery(Delivery(request, Route("r1", "r0", "request"), 18))
        near = [Request(SCHEMA, RUN, step, 0, 1, 7) for step in range(1, PENDING_LIMIT + 100)]
        for request in near:
            recorder.on_delivery(Delivery(request, Route("r1", "r0", "request"), 18))
    assert len(recorder.pending) == AHEAD_STEPS + 1  # steps 1..1+64: no tick yet
    assert recorder.dropped_ahead == forged + len(near) - (AHEAD_STEPS + 1)


def test_a_flood_of_requests_draws_a_bounded_number_of_answers() -> None:
    node, world = make_node(robot=2)
    node.handle(world.measurement(2))
    flood = [Request(SCHEMA, RUN, 1, 1, 2, 5000 + i) for i in range(1000)]
    answers = [out for request in flood for out in node.handle(request)]
    assert len(answers) == 4 and all(isinstance(message, Reply) for _, message in answers)
    assert node.rate_limited == 996
    other = node.handle(Request(SCHEMA, RUN, 1, 3, 2, 42))  # the other neighbour is not starved
    assert len(other) == 1


@pytest.mark.processes
def test_a_forged_end_that_empties_the_ring_ends_the_run_as_failed(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    spawn = start_spawn(runs, "--steps", "3000")
    try:
        folder = wait_for_steps(runs, 50)
        run = json.loads((folder / "run.json").read_text())
        keys = Keys(int(run["run"], 16))
        with open_session(BusConfig(connect=tuple(run["connect"]))) as session:
            time.sleep(0.5)
            session.put(keys.data(BROADCAST, WORLD, "end"), encode(End(SCHEMA, keys.run, 50, "done", 1.0)))
            time.sleep(0.5)
        stdout, stderr = (stream.decode() for stream in spawn.communicate(timeout=60))
    finally:
        stop_all(spawn)
    summary = json.loads((folder / "summary.json").read_text())
    assert spawn.returncode == 1
    assert not summary.get("converged")
    assert summary["failures"] == {"world": 1}
    assert "every robot left the ring by step" in stderr
    assert processes_mentioning(str(folder)) == []


FLOOD_PAYLOADS = 30  # of 10 MiB each: 300 MiB, which a monitor that buffered them would hold at once
FLOOD_RSS_KIB = 200_000  # a six-robot monitor peaks near 90 MB; one that buffered the flood, above 350 MB


@pytest.mark.processes
def test_a_flood_of_oversized_payloads_is_dropped_at_the_link_and_the_monitor_holds_its_memory(
        tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    spawn = start_spawn(runs, "--steps", "3000")
    try:
        folder = wait_for_steps(runs, 20)
        run = json.loads((folder / "run.json").read_text())
        keys = Keys(int(run["run"], 16))
        with open_session(BusConfig(connect=tuple(run["connect"]))) as session:
            time.sleep(0.5)
            publisher = session.declare_publisher(keys.data("monitor", "r1", "stats"))
            blob = bytes(10 << 20)
            for _ in range(FLOOD_PAYLOADS):
                publisher.put(blob)
            time.sleep(1.0)
            publisher.undeclare()
        spawn.communicate(timeout=200)
    finally:
        stop_all(spawn)
    assert spawn.returncode == 0  # the run went on, its books untouched
    end = json.loads((folder / "log.jsonl").read_text().splitlines()[-1])
    assert end["type"] == "end" and end["consistent"] is True
    assert end["rss_kib"]["monitor"] < FLOOD_RSS_KIB, end["rss_kib"]
    assert "size" not in end["rejected"]  # none of them even reached the monitor's door
