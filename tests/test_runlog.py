"""Reading run logs back (tools/runlog/log.py read_log): every damaged record is one line of error
naming its line and problem, exit code 2, never a traceback."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from ringtrack.tools.cli import main
from ringtrack.tools.runlog.log import read_log
from tests.helpers import RINGTRACK

pytestmark = pytest.mark.timeout(60)

DAMAGED = "the file is damaged or not a ringtrack run log"


@pytest.fixture(scope="module")
def engine_log(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The lines of a 3-step engine log of 6 robots: header, 3 steps, end."""
    path = tmp_path_factory.mktemp("log") / "run.jsonl"
    assert main(["simulate", "--steps", "3", "--log", str(path)]) == 0
    lines = path.read_text().splitlines()
    assert [json.loads(line)["type"] for line in lines] == ["header", "step", "step", "step", "end"]
    return lines


def edited(field: str, change: Callable[[dict], None]) -> Callable[[list[str]], list[str]]:
    """An edit of a log's lines: ``change`` applied to the record of line 1 (``field`` "header") or 3."""
    def edit(lines: list[str]) -> list[str]:
        number = 0 if field == "header" else 2
        record = json.loads(lines[number])
        change(record)
        return [*lines[:number], json.dumps(record), *lines[number + 1:]]
    return edit


CASES = {
    "a number": (lambda lines: [lines[0], "42", *lines[1:]],
                 "line 2: Expected `object`, got `int`"),
    "a list": (lambda lines: [*lines[:2], "[1, 2]", *lines[2:]],
               "line 3: Expected `object`, got `array`"),
    "no positions": (edited("step", lambda record: record.pop("positions")),
                     "line 3: step record: Object missing required field `positions`"),
    "a position short": (edited("step", lambda record: record["positions"].pop()),
                         "line 3: step record: `positions` has 5 entries for a team of 6 robots"),
    "a text coordinate": (edited("step", lambda record: record["positions"][0].__setitem__(1, "x")),
                          "line 3: step record: Expected `float`, got `str` - at `$.positions[0][1]`"),
    "no clock": (edited("header", lambda record: record.pop("clock")),
                 "line 1: header record: Object missing required field `clock`"),
    "a fault off the team": (lambda lines: [*lines[:2], '{"type": "event", "event": "dropped", "step": 1, '
                                            '"sender": 0, "receiver": 6, "reason": "drop"}', *lines[2:]],
                             "line 3: dropped event: `sender` and `receiver` must be robots 0..5"),
}


@pytest.mark.processes
@pytest.mark.parametrize("case", CASES)
def test_a_damaged_record_is_one_line_and_exit_2(case: str, engine_log: list[str], tmp_path: Path) -> None:
    edit, problem = CASES[case]
    path = tmp_path / "damaged.jsonl"
    path.write_text("\n".join(edit(engine_log)) + "\n")
    replay = subprocess.run([*RINGTRACK, "replay", str(path), "--final"], capture_output=True, text=True, timeout=30)
    assert replay.returncode == 2
    assert replay.stderr == f"ringtrack: error: {path}: {problem}; {DAMAGED}\n"
    assert replay.stdout == ""


def test_plot_reads_logs_the_same_way(engine_log: list[str], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    edit, problem = CASES["a position short"]
    path = tmp_path / "damaged.jsonl"
    path.write_text("\n".join(edit(engine_log)) + "\n")
    assert main(["plot", str(path), "-o", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == f"ringtrack: error: {path}: {problem}; {DAMAGED}\n"
    assert not (tmp_path / "x.png").exists()


def test_an_intact_log_keeps_its_records_in_file_order(engine_log: list[str], tmp_path: Path) -> None:
    event = {"type": "event", "event": "delayed", "step": 2, "subject": "reply", "sender": 1, "receiver": 0,
             "reason": None, "delay_s": 0.05}
    path = tmp_path / "run.jsonl"
    path.write_text("\n".join([*engine_log[:2], json.dumps(event), *engine_log[2:]]) + "\n")
    log = read_log(path)
    assert [record["type"] for record in log.records] == ["step", "event", "step", "step"]
    assert log.events == [event] and [record["step"] for record in log.steps] == [1, 2, 3]
    assert log.end is not None and log.end["reason"] == "done" and log.scenario.robots == 6
