"""Foxglove views of a run (tools/viz): MCAP from ``export --mcap`` and ``spawn --record`` read back
with the ``mcap`` reader, a live ``spawn --foxglove`` team watched by a WebSocket client speaking the
Foxglove protocol, and ``plot --animate`` counted frame by frame."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import struct
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
from mcap.reader import make_reader
from PIL import Image

from ringtrack.agents import engine
from ringtrack.tools.cli import main
from ringtrack.tools.runlog.derived import fired_links, team_energy
from ringtrack.tools.runlog.log import RunLog, read_log, write_engine_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.tools.viz.scene import PER_STEP, TOPICS, nanoseconds
from ringtrack.world.scenario import load_scenario
from tests.helpers import start_spawn, stop_all

SCHEMAS = {topic: f"foxglove.{schema}" for topic, schema in TOPICS.items() if schema != "json"} | {
    "/metrics": "ringtrack.StepMetrics", "/energy": "ringtrack.RadioEnergy"}


def read_mcap(path: Path) -> tuple[dict[str, str], dict[str, list[int]]]:
    """Schema name and log times (ns) of every message, by topic."""
    schemas: dict[str, str] = {}
    times: dict[str, list[int]] = defaultdict(list)
    with path.open("rb") as file:
        for schema, channel, message in make_reader(file).iter_messages(log_time_order=False):
            schemas[channel.topic] = schema.name
            times[channel.topic].append(message.log_time)
    return schemas, times


def assert_mcap_holds_the_log(path: Path, log: RunLog) -> None:
    """Every channel with its schema; one message per step on the per-step channels, stamped with
    the steps' simulated times (rising); a Log entry per event and one for the end."""
    schemas, times = read_mcap(path)
    assert schemas == SCHEMAS
    step_times = [nanoseconds(record["time"]) for record in log.steps]
    assert all(later > earlier for earlier, later in zip(step_times, step_times[1:], strict=False))
    for topic in PER_STEP:
        assert times[topic] == step_times, topic
    assert len(times["/log"]) == len(log.events) + 1
    assert len(times["/energy"]) == 1
    # the team's radio energy so far, per step, as the step records hold it (rising, positive once polled)
    energy = [metrics["energy_j"] for metrics in metrics_of(path)]
    assert energy == [team_energy(record) for record in log.steps]
    assert all(later >= earlier for earlier, later in zip(energy, energy[1:], strict=False)) and energy[-1] > 0


def metrics_of(path: Path) -> list[dict[str, Any]]:
    """The JSON messages of ``/metrics``, in log-time order."""
    with path.open("rb") as file:
        return [json.loads(message.data) for _, channel, message in make_reader(file).iter_messages()
                if channel.topic == "/metrics"]


def test_export_mcap_of_an_engine_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log_path, mcap = tmp_path / "run.jsonl", tmp_path / "run.mcap"
    assert main(["simulate", "authors-moving", "--steps", "30", "--log", str(log_path)]) == 0
    assert main(["export", str(log_path), "--mcap", str(mcap)]) == 0
    assert f"wrote {mcap} (30 steps, 0 events)" in capsys.readouterr().out
    assert_mcap_holds_the_log(mcap, read_log(log_path))


def test_fired_links_are_the_logged_messages_the_probes_and_the_drops() -> None:
    record = {"step": 4, "trigger": [1, 0, 0], "links": [["reply", 1, 0, 1], ["request", 0, 1, 1],
                                                         ["request", 2, 1, 1]]}
    dropped = {"type": "event", "event": "dropped", "step": 4, "subject": "request", "sender": 0, "receiver": 2,
               "reason": "outage"}
    elsewhere = {**dropped, "step": 3}
    links = {(link.kind, link.sender, link.receiver, link.dropped) for link in fired_links(record, [dropped, elsewhere])}
    assert links == {("reply", 1, 0, None), ("request", 0, 1, None), ("probe", 2, 1, None),
                     ("request", 0, 2, "outage")}


def test_animate_writes_a_frame_every_k_steps(tmp_path: Path) -> None:
    log_path, gif = tmp_path / "run.jsonl", tmp_path / "team.gif"
    assert main(["simulate", "authors-moving", "--steps", "23", "--log", str(log_path)]) == 0
    assert main(["plot", str(log_path), "--animate", str(gif), "--every", "5", "--fps", "4"]) == 0
    with Image.open(gif) as image:
        assert image.n_frames == 5  # steps 1, 6, 11, 16, 21


@pytest.mark.parametrize("flags", [["export", "LOG", "--mcap", "OUT.mcap"], ["spawn", "--record", "OUT.mcap"],
                                   ["spawn", "--foxglove", "8765"], ["monitor", "--log", "OUT.jsonl", "--foxglove", "0"]])
def test_without_the_extra_one_line_names_it(tmp_path: Path, flags: list[str], monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove raises ImportError
    argv = [str(tmp_path / flag) if flag.isupper() or "." in flag and not flag[0].isdigit() else flag
            for flag in flags]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "pip install 'ringtrack[viz]'" in error
    assert not list(tmp_path.glob("runs"))  # nothing started


@pytest.mark.parametrize(("text", "line"), [("{\"not\": \"a log\"}\n", 1), ("\n\nplain text\n{}\n", 3)])
def test_a_foreign_log_is_one_line_naming_the_file_and_line(tmp_path: Path, text: str, line: int,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    foreign = tmp_path / "foreign.jsonl"
    foreign.write_text(text)
    assert main(["export", str(foreign), "--mcap", str(tmp_path / "out.mcap")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and f"{foreign}: line {line}" in error


@pytest.mark.processes
@pytest.mark.timeout(240)
def test_record_of_a_lockstep_team_holds_its_log_and_equals_the_engine_log(tmp_path: Path) -> None:
    """The MCAP a team records while it runs holds what its run log holds; the log's new per-step
    fields (each estimate's covariance, the messages per link) equal those of the engine's log."""
    steps, recording = 60, tmp_path / "team.mcap"
    scenario = load_scenario("authors-moving", max_steps=steps)
    result = spawn_team(TeamPlan(scenario=scenario, runs=tmp_path / "runs", dashboard=False, quiet=True,
                                 record=recording))
    assert result.exit_code == 0
    log = read_log(Path(result.log))
    assert len(log.steps) == steps
    assert_mcap_holds_the_log(recording, log)
    history = engine.run(scenario, seeds=scenario.seed, steps=steps)
    write_engine_log(tmp_path / "engine.jsonl", history)
    twin = read_log(tmp_path / "engine.jsonl")
    # the robots' own energy counts: by the end, what the engine's radio model says of the same messages;
    # step by step (the steps before each), the engine's sums of the same energies
    assert history.energy is not None
    assert sum(map(sum, log.end["energy_j"].values())) == pytest.approx(float(history.energy.sum()), rel=1e-9)
    for logged, computed in zip(log.steps, twin.steps, strict=True):
        np.testing.assert_allclose(logged["energy_j"], computed["energy_j"], rtol=1e-9, atol=1e-15)
        assert logged["links"] == computed["links"]
        assert np.allclose(np.array(logged["covariance"], dtype=float), np.array(computed["covariance"], dtype=float),
                           rtol=0.0, atol=1e-9)


# ---------------------------------------------------------------------------- live
def protobuf_fields(data: bytes) -> list[tuple[int, int, Any]]:
    """``(field number, wire type, value)`` of a protobuf message: ints, 8-byte and length-delimited bytes."""
    fields, at = [], 0

    def varint() -> int:
        nonlocal at
        value = shift = 0
        while True:
            byte = data[at]
            at += 1
            value |= (byte & 0x7F) << shift
            shift += 7
            if byte < 0x80:
                return value

    while at < len(data):
        key = varint()
        number, wire = key >> 3, key & 7
        if wire == 0:
            value: Any = varint()
        elif wire == 1:
            value, at = data[at:at + 8], at + 8
        elif wire == 2:
            size = varint()
            value, at = data[at:at + size], at + size
        elif wire == 5:
            value, at = data[at:at + 4], at + 4
        else:
            raise AssertionError(f"wire type {wire}")
        fields.append((number, wire, value))
    return fields


def descriptors(schema: bytes) -> dict[str, dict[str, tuple[int, int, str]]]:
    """Message name -> field name -> (number, type, type name), from a FileDescriptorSet."""
    messages: dict[str, dict[str, tuple[int, int, str]]] = {}
    for number, _, file in protobuf_fields(schema):
        assert number == 1
        fields = protobuf_fields(file)
        package = next((value.decode() for n, _, value in fields if n == 2), "")
        for n, _, message in fields:
            if n == 4:
                parts = protobuf_fields(message)
                name = next(value.decode() for k, _, value in parts if k == 1)
                table = messages.setdefault(f".{package}.{name}", {})
                for k, _, field in parts:
                    if k == 2:
                        entries = {key: value for key, _, value in protobuf_fields(field)}
                        table[entries[1].decode()] = (entries[3], entries[5], entries.get(6, b"").decode())
    return messages


def decode(data: bytes, message: str, types: dict[str, dict[str, tuple[int, int, str]]]) -> dict[str, list[Any]]:
    """A protobuf message as field name -> values (doubles, strings, nested dicts), by its descriptor."""
    by_number = {number: (name, kind, type_name) for name, (number, kind, type_name) in types[message].items()}
    decoded: dict[str, list[Any]] = defaultdict(list)
    for number, _, value in protobuf_fields(data):
        if number not in by_number:
            continue
        name, kind, type_name = by_number[number]
        if kind == 1:
            decoded[name].append(struct.unpack("<d", value)[0])
        elif kind == 9:
            decoded[name].append(value.decode())
        elif kind == 11:
            decoded[name].append(decode(value, type_name, types))
        else:
            decoded[name].append(value)
    return decoded


async def watch(url: str, topic: str, wanted: int, timeout_s: float) -> tuple[str, bytes, list[tuple[int, bytes]]]:
    """Subscribe to ``topic`` and return its schema name, its schema and ``wanted`` (log time, payload) messages."""
    messages: list[tuple[int, bytes]] = []
    # The SDK's server (0.30) speaks the protocol's current subprotocol, foxglove.sdk.v1 (what the
    # Foxglove app asks for); foxglove.websocket.v1 is its former name.
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as socket:
        assert socket.subprotocol in SUBPROTOCOLS
        channel: dict[str, Any] | None = None
        deadline = time.monotonic() + timeout_s
        while len(messages) < wanted:
            frame = await asyncio.wait_for(socket.recv(), max(0.1, deadline - time.monotonic()))
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise" and channel is None:
                    channel = next((c for c in op["channels"] if c["topic"] == topic), None)
                    if channel is not None:
                        await socket.send(json.dumps({"op": "subscribe",
                                                      "subscriptions": [{"id": 7, "channelId": channel["id"]}]}))
            elif frame[0] == 1:  # message data: subscription id, log time, payload
                subscription, log_time = struct.unpack_from("<IQ", frame, 1)
                assert subscription == 7
                messages.append((log_time, frame[13:]))
    assert channel is not None
    return channel["schemaName"], base64.b64decode(channel["schema"]), messages


SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def live_url(runs: Path, timeout_s: float = 60.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for stderr in runs.glob("*/monitor.stderr"):
            for line in stderr.read_text(errors="replace").splitlines():
                if "Foxglove live view on " in line:
                    return line.split("Foxglove live view on ")[1].strip()
        time.sleep(0.05)
    raise AssertionError(f"no monitor announced a Foxglove live view under {runs} within {timeout_s} s")


@pytest.mark.processes
@pytest.mark.timeout(240)
def test_a_live_team_serves_scene_updates_whose_robots_stand_where_the_world_put_them(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    spawn = start_spawn(runs, "authors-moving", "--steps", "5000", "--foxglove", "0")
    try:
        url = live_url(runs)
        assert url.startswith("ws://127.0.0.1:")
        schema_name, schema, received = asyncio.run(watch(url, "/robots", 20, timeout_s=90.0))
        os.killpg(spawn.pid, signal.SIGINT)
        spawn.wait(timeout=60)
    finally:
        stop_all(spawn)
    assert schema_name == "foxglove.SceneUpdate"
    types = descriptors(schema)
    log = read_log(next(runs.glob("*/log.jsonl")))
    by_time = {nanoseconds(record["time"]): record for record in log.steps}
    checked = Counter[str]()
    for log_time, payload in received:
        record = by_time[log_time]  # a step the run log holds
        update = decode(payload, ".foxglove.SceneUpdate", types)
        for entity in update["entities"]:
            robot = int(entity["id"][0].removeprefix("r"))
            position = entity["spheres"][0]["pose"][0]["position"][0]
            assert [position["x"][0], position["y"][0]] == record["positions"][robot]
            checked[entity["id"][0]] += 1
    assert set(checked) == {f"r{robot}" for robot in range(6)} and min(checked.values()) == len(received)
