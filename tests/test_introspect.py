"""Looking at a live run from outside: ``ringtrack list``, ``echo`` and ``hz`` (tools/introspect/watch.py,
bus/observer.py) see it as it is and change nothing."""

from __future__ import annotations

import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from ringtrack.bus.keys import Route, parse_any
from ringtrack.bus.messages import SCHEMA, Rejected, Request, encode, peek
from ringtrack.bus.observer import Heard
from ringtrack.tools.cli import main
from ringtrack.tools.introspect.watch import echo_line
from ringtrack.tools.runlog.log import read_log
from tests.helpers import RINGTRACK, assert_equals_engine, processes_mentioning, start_spawn, stop_all

pytestmark = pytest.mark.timeout(240)


def test_keys_of_any_run_and_lines_of_any_message() -> None:
    assert parse_any("ringtrack/0000002a/r1/r0/request") == (42, Route("r1", "r0", "request"))
    assert parse_any("ringtrack/zz/r1/r0/request") is None and parse_any("ringtrack/2a/alive/r0") is None
    payload = encode(Request(SCHEMA, 42, 7, 0, 1, 99))
    message = peek(payload)
    heard = Heard(42, Route("r1", "r0", "request"), "ringtrack/0000002a/r1/r0/request", payload, 0.0)
    line = f"request     r0>r1         {len(payload):>4} B step 7: sender=0 receiver=1 nonce=99"
    assert echo_line(heard, message) == line
    with pytest.raises(Rejected):
        peek(b"junk")
    assert echo_line(heard, None).endswith("(not a message: dropped by every participant)")


def test_bad_run_arguments_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["echo", "not-a-run", "--runs", str(tmp_path)]) == 2
    assert "RUN 'not-a-run': give a run folder (holding run.json) or a run id in hex" in capsys.readouterr().err
    assert main(["hz", "1f2e3d4c", "--runs", str(tmp_path)]) == 2
    assert "give --connect ENDPOINT" in capsys.readouterr().err


def ringtrack(*arguments: str) -> str:
    """Run a ringtrack command as its own process (as a user would attach one) and return its output."""
    done = subprocess.run([*RINGTRACK, *arguments], capture_output=True, timeout=60, env={"COLUMNS": "200",
                          "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stderr.decode()
    return done.stdout.decode()


@pytest.mark.processes
def test_a_lockstep_run_watched_by_list_echo_and_hz_equals_the_engine(tmp_path: Path) -> None:
    # a run that outlasts the watching however loaded the machine, stopped (Ctrl-C) once watched
    process = start_spawn(tmp_path, "--steps", "100000")
    try:
        deadline = time.monotonic() + 60
        while not (logs := list(tmp_path.glob("*/log.jsonl"))) or b'"type":"step"' not in logs[0].read_bytes():
            assert time.monotonic() < deadline and process.poll() is None
            time.sleep(0.05)
        folder = next(tmp_path.glob("*/run.json")).parent
        listed = ringtrack("list", str(folder), "--duration", "0.5")
        run = folder.name.rsplit("-", 1)[-1]
        assert f"run {run}: 8 participants, 8 alive" in listed  # the observer itself is no participant
        for name in ("world", "monitor", *(f"r{robot}" for robot in range(6))):
            assert re.search(rf"^│ {name} +│ alive ", listed, re.MULTILINE), listed
        assert f"ringtrack/{run}/monitor/world/digest" in listed  # the ticks travel in the digests
        echoed = ringtrack("echo", str(folder), "--kind", "measurement", "--robot", "2", "--count", "5").splitlines()
        assert len(echoed) == 5
        assert all(re.match(r"measurement world>r2 +\d+ B step \d+: time=", line) for line in echoed), echoed
        firsts = [int(re.search(r"step (\d+)", line).group(1)) for line in echoed]
        # in step order, one per step; an observer is not a participant, and a busy machine's bus may
        # drop a sample to it (the robots' own samples are what the run's equality with the engine shows)
        assert firsts == sorted(set(firsts))
        # a loaded machine may hold the whole team for a period: listen again until a period heard it
        for _ in range(10):
            rates = ringtrack("hz", str(folder), "--reports", "1", "--period", "0.5")
            if "nothing heard" not in rates:
                break
        assert re.search(r"measurement │ +\d+\.\d │ +\d+ │ +\d+\.\d", rates), rates
        assert re.search(r"world>r0 │", rates), rates
        assert re.search(r"world>monitor │ +\d+\.\d │ +\d+ │ +\d+\.\d", rates), rates
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=60)
        code = process.returncode
    finally:
        stop_all(process)
    assert code == 130  # stopped as asked
    log = read_log(folder / "log.jsonl")
    assert log.end["rejected"] == {}  # watching put nothing on the team's keys
    assert_equals_engine(log)  # and changed nothing it did
    assert processes_mentioning(str(folder)) == []


def test_echo_and_hz_give_up_on_a_run_that_is_not_running(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from ringtrack.world.scenario import load_scenario

    folder = tmp_path / "20261201T000000Z-paper-stationary-0000abcd"
    folder.mkdir()
    (folder / "scenario.toml").write_bytes(load_scenario("paper-stationary").to_toml())
    (folder / "run.json").write_text(json.dumps({"run": "0000abcd", "connect": ["tcp/127.0.0.1:9"]}))
    started = time.monotonic()
    assert main(["echo", str(folder), "--give-up", "0.5"]) == 1
    assert "echo: nothing of run 0000abcd heard for 0.5 s: is it running?" in capsys.readouterr().err
    assert main(["hz", "abcd", "--runs", str(tmp_path), "--period", "10", "--give-up", "0.5"]) == 1
    assert "hz: nothing of run 0000abcd heard for 0.5 s" in capsys.readouterr().err
    assert time.monotonic() - started < 30
    assert main(["list", str(folder), "--duration", "0.2"]) == 0
    listed = capsys.readouterr().out
    assert "run 0000abcd: 8 participants, 0 alive" in listed and listed.count(" gone ") == 8


def test_a_run_that_ends_ends_echo_and_hz_cleanly_with_what_they_heard(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """The world withdrawing its token ends the watch with exit code 0; hz first reports the
    messages it counted since its last report (none are lost), echo has printed each one."""
    import json

    from ringtrack.bus.observer import Token
    from ringtrack.tools.introspect import watch as introspect
    from ringtrack.world.scenario import load_scenario

    folder = tmp_path / "20261201T000000Z-paper-stationary-0000abcd"
    folder.mkdir()
    (folder / "scenario.toml").write_bytes(load_scenario("paper-stationary").to_toml())
    (folder / "run.json").write_text(json.dumps({"run": "0000abcd", "connect": ["tcp/127.0.0.1:9"]}))
    payload = encode(Request(SCHEMA, 0xABCD, 7, 1, 2, 5))

    class EndingRun:
        def __enter__(self) -> EndingRun:
            self.batches = [[Heard(0xABCD, parse_any("ringtrack/0000abcd/r2/r1/request")[1],
                                   "ringtrack/0000abcd/r2/r1/request", payload, time.monotonic())] * 3,
                            [Token(0xABCD, "world", False, time.monotonic())]]
            return self

        def __exit__(self, *exc: object) -> None:
            pass

        def poll(self) -> list[Heard | Token]:
            return self.batches.pop(0) if self.batches else []

    monkeypatch.setattr(introspect, "observer", lambda target, mode: EndingRun())
    assert main(["hz", str(folder), "--period", "60"]) == 0
    captured = capsys.readouterr()
    assert re.search(rf"request │ +\d+\.\d │ +\d+ │ +{len(payload)}\.0$", captured.out, re.MULTILINE), captured.out
    assert re.search(r"r1>r2 │", captured.out), captured.out
    assert captured.err.strip() == "hz: the world left: the run is over"
    assert main(["echo", str(folder)]) == 0
    captured = capsys.readouterr()
    assert captured.out.count("request     r1>r2") == 3, captured.out
    assert captured.err.strip() == "echo: the world left: the run is over"
