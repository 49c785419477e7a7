"""A monitor killed and restarted by the nemesis: the world holds the run and replays the steps it
kept, the new monitor resumes the same log and the books (exactly, where the world's digests
account for the traffic; naming what it could not see, where it observes the wire itself)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest

from ringtrack.bus.counting import TrafficCounter, close_books
from ringtrack.bus.messages import SCHEMA, Digest, DigestEntry, Stats, Tick
from ringtrack.tools.monitor.checkpoint import Checkpoint, checkpoint_path, read_checkpoint, write_checkpoint
from ringtrack.tools.monitor.monitor import PENDING_LIMIT, Recorder, replayed
from ringtrack.tools.runlog.log import LogWriter, read_log
from ringtrack.world.backlog import step_entries
from tests.helpers import RINGTRACK, assert_equals_engine, processes_mentioning, scenario

RUN = 0x2000ABCD


def test_a_resumed_log_goes_on_after_its_last_whole_record(tmp_path: Path) -> None:
    path = tmp_path / "log.jsonl"
    path.write_bytes(b'{"type":"header"}\n{"type":"step","step":1,"time":0.1}\n{"type":"step","step":2,"time":0.2}\n'
                     b'{"type":"st')
    writer = LogWriter(path, resume=True)
    assert writer.steps_written == 2
    writer.write({"type": "step", "step": 3, "time": 0.3})
    writer.close()
    assert path.read_bytes().splitlines()[-2:] == [b'{"type":"step","step":2,"time":0.2}',
                                                   b'{"type":"step","step":3,"time":0.3}']


def test_a_checkpoint_is_read_back_only_for_its_own_run(tmp_path: Path) -> None:
    stats = Stats(1, 7, "r1", True, [("request", "r1", "r2", 3, 48)], [], {}, 1000)
    checkpoint = Checkpoint("00000007", 41, 44, 1, 0, [("command", "r1", "world", 44, 3520)], {"value": 2}, [],
                            {"r1": stats}, ["r3"], {"r3": 2}, {"r3": [1, 2]}, {"r3": 2})
    path = checkpoint_path(tmp_path / "log.jsonl")
    write_checkpoint(path, checkpoint)
    assert path.name == "log.checkpoint.json" and not list(tmp_path.glob("*.partial"))
    assert read_checkpoint(path, "00000007") == checkpoint
    assert read_checkpoint(path, "00000008") is None  # another run's
    path.write_text("{")
    assert read_checkpoint(path, "00000007") is None


def test_a_resumed_monitors_shortfalls_are_unobserved_and_its_excesses_unexplained() -> None:
    said = [("request", "r3", "r2", 10, 160), ("command", "r1", "world", 50, 4000)]
    seen = [("request", "r3", "r2", 8, 128), ("command", "r1", "world", 51, 4080)]
    books = close_books(said, seen, cut_off=set(), categories=("robot", "world"), unobserved=True)
    assert books.unobserved == {("request", "r3", "r2"): 2}
    assert books.unexplained == {("command", "r1", "world"): (50, 51)}
    assert books.lines() == [
        "request r3 > r2: 2 sent while the monitor was away, unseen by the monitor that resumed its books (unobserved)",
        "command r1 > world: 50 sent, 51 seen (unexplained)"]
    assert close_books(said, seen[:1], cut_off=set(), categories=("robot",), unobserved=True).balanced
    assert not close_books(said, seen[:1], cut_off=set(), categories=("robot",)).balanced


def test_a_step_with_more_commands_than_robots_takes_further_entries() -> None:
    entries = step_entries(5, None, [(0, 40)], [("a", 1), ("b", 2), ("c", 3)], team=2)  # type: ignore[list-item]
    assert [(entry.step, entry.measurements, entry.commands) for entry in entries] == [
        (5, [(0, 40)], [("a", 1), ("b", 2)]), (5, [], [("c", 3)])]


def spawn_with_monitor_restart(runs: Path, *arguments: str) -> tuple[subprocess.CompletedProcess, Path]:
    done = subprocess.run([*RINGTRACK, "spawn", *arguments, "--no-dashboard", "--runs", str(runs),
                           "--nemesis", "kill monitor@1s, restart monitor@3s"], capture_output=True, text=True,
                          timeout=280)
    (folder,) = runs.iterdir()
    return done, folder


def assert_resumed(folder: Path, steps: int) -> dict:
    """The world held the run and the restarted monitor resumed its log: every step written once, in
    order, the run ended whole; returns the end record."""
    world = (folder / "world.stderr").read_text()
    assert "the monitor went away at step" in world and "the run holds for up to 32 s" in world
    assert "the monitor is back after" in world
    assert [json.loads(line)["fault"] for line in (folder / "nemesis.jsonl").read_text().splitlines()] == [
        "kill monitor@1s", "restart monitor@3s"]
    log = read_log(folder / "log.jsonl")
    assert [record["step"] for record in log.steps] == list(range(1, steps + 1))
    assert [event["subject"] for event in log.events if event["event"] == "monitor"] == ["resumed"]
    assert log.end is not None and log.end["steps"] == steps and log.end["reason"] == "done"
    assert not checkpoint_path(folder / "log.jsonl").exists()  # the log is whole: nothing left to resume
    assert processes_mentioning(str(folder)) == []
    return log.end


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_a_restarted_monitor_resumes_the_log_and_the_lockstep_books_close_exactly(tmp_path: Path) -> None:
    done, folder = spawn_with_monitor_restart(tmp_path, "paper-stationary", "--steps", "4000")
    assert done.returncode == 0, done.stderr
    end = assert_resumed(folder, 4000)
    assert end["books"] == [] and end["consistent"] is True  # the replayed digests count what it missed
    assert_equals_engine(read_log(folder / "log.jsonl"))


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(300)
def test_a_restarted_auditing_monitor_resumes_the_log_and_names_what_it_could_not_see(tmp_path: Path) -> None:
    done, folder = spawn_with_monitor_restart(tmp_path, "authors-moving", "--clock", "realtime", "--rate", "5",
                                              "--steps", "400", "--lease", "2", "--audit")
    assert done.returncode == 0, done.stderr
    end = assert_resumed(folder, 400)
    assert end["consistent"] is True
    assert all(line.endswith("(unobserved)") for line in end["books"]), end["books"]
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["distrust"] is None and summary["failures"] == {}


def tick(step: int) -> Tick:
    return Tick(SCHEMA, RUN, step, 0.1 * step, [(0.0, 0.0)] * 6, (1.0, 1.0), list(range(6)))


def test_a_step_that_waits_long_is_written_before_it_crowds_later_ones_out(tmp_path: Path) -> None:
    with LogWriter(tmp_path / "log.jsonl") as writer:
        recorder = Recorder(writer, scenario(), force_after_s=1e9)  # never overdue by time
        for step in range(1, PENDING_LIMIT // 2 + 1):  # ticks without commands: no step is complete
            recorder.on_tick(tick(step))
        recorder.flush()
    assert writer.steps_written == 1 and recorder.next_step == 2 and len(recorder.pending) == PENDING_LIMIT // 2 - 1


def test_a_resumed_monitor_writes_the_replayed_steps_at_once_whatever_they_lack(tmp_path: Path) -> None:
    with LogWriter(tmp_path / "log.jsonl") as writer:
        recorder = Recorder(writer, scenario(), force_after_s=1e9)
        digest = Digest(SCHEMA, RUN, [DigestEntry(step, tick(step), [], []) for step in (1, 2, 3)], replayed=True)
        participant = SimpleNamespace(counter=TrafficCounter())
        replayed(participant, recorder, digest, digests=True, recount_after=2)  # type: ignore[arg-type]
    assert writer.steps_written == 3 and recorder.next_step == 4
    assert recorder.digested_through == 3  # counted: the steps after the predecessor's checkpoint
