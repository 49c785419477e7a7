"""The ``ringtrack`` command line, in-process (no team is started here)."""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from rich.table import Table

from ringtrack.agents import engine
from ringtrack.tools.cli import main
from ringtrack.tools.cli.options import scheduler_address, team_sizes
from ringtrack.tools.output.console import show
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.world.scenario import load_scenario


def test_simulate_json_summary(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    assert main(["simulate", "paper-stationary", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["strategy"] == "self" and result["robots"] == 6 and result["seed"] == 0
    assert result["converged"] is True and result["ctime"] == 712 and result["steps"] == 712
    assert result["triggers"]["total"] == sum(result["triggers"]["per_robot"])
    assert 0 < result["com_bar"] < 0.3
    assert result["cerr_final_deg"] < 0.6


def test_simulate_flags_override_the_scenario(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    assert main(["simulate", "--strategy", "constant", "--robots", "8", "--seed", "3", "--steps", "50",
                 "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert (result["strategy"], result["robots"], result["seed"], result["steps"]) == ("constant", 8, 3, 50)
    assert result["triggers"]["per_robot"] == [50] * 8


def test_simulate_log_reads_back_as_the_engine_run(tmp_path: Path) -> None:
    path = tmp_path / "log.jsonl"
    assert main(["simulate", "--steps", "120", "--log", str(path)]) == 0
    logged = history_from_log(read_log(path))
    twin = engine.run(load_scenario("paper-stationary"), steps=120)
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-12
    assert np.array_equal(logged.triggers, twin.triggers)
    assert np.allclose(logged.cerr_memory, twin.cerr_memory, atol=1e-9)


def test_stationary_experiment_json_and_figure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data, figure = tmp_path / "e.json", tmp_path / "e.png"
    assert main(["experiment", "stationary", "--workers", "1", "--robots", "4,6", "--trials", "5", "--seed", "2",
                 "--json", str(data), "--plot", str(figure)]) == 0
    table = capsys.readouterr().out
    assert "Com ÷" in table and "…" not in table  # the table fits 80 columns: nothing cut
    result = json.loads(data.read_text())
    assert len(result["rows"]) == 2 * 2 * 5
    assert {row["seed"] for row in result["rows"]} == {2, 3, 4, 5, 6}
    summary = {(entry["robots"], entry["strategy"]): entry for entry in result["summary"]}
    for robots in (4, 6):
        rows = [row for row in result["rows"] if row["robots"] == robots and row["strategy"] == "self"]
        assert summary[robots, "self"]["ctime_mean"] == pytest.approx(np.mean([row["ctime"] for row in rows]))
        assert summary[robots, "constant"]["com_bar_mean"] == 1.0
        for row in result["rows"]:  # Com-bar = polls of steps 1..Ctime / (N Ctime), each trial its own Ctime
            assert row["com_bar"] == pytest.approx(row["triggers"] / (row["robots"] * row["ctime"]))
        (ratio,) = [entry for entry in result["ratios"] if entry["robots"] == robots]
        assert ratio["ctime_ratio"] == pytest.approx(summary[robots, "self"]["ctime_mean"] /
                                                     summary[robots, "constant"]["ctime_mean"])
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(("text", "sizes"), [
    ("6", [6]), ("3,6,10,20", [3, 6, 10, 20]), ("3-6", [3, 4, 5, 6]), ("3-30:9", [3, 12, 21, 30]),
    (" 3, 5-8 ", [3, 5, 6, 7, 8]), ("4-4", [4]),
])
def test_team_sizes_are_numbers_lists_and_ranges(text: str, sizes: list[int]) -> None:
    assert team_sizes(text) == sizes


@pytest.mark.parametrize(("text", "problem"), [
    ("3..6", "give team sizes like 6, 3,6,10,20, 3-30 or 3-30:3"),
    ("six", "give team sizes like 6, 3,6,10,20, 3-30 or 3-30:3"),
    ("6-3", "6-3 is no range; give FIRST-LAST[:STEP], FIRST <= LAST, STEP >= 1, e.g. 3-30:3"),
    ("3-9:0", "3-9:0 is no range; give FIRST-LAST[:STEP], FIRST <= LAST, STEP >= 1, e.g. 3-30:3"),
    ("2-5", "every team needs at least 3 robots"),
    ("", "every team needs at least 3 robots"),
    ("3,4-6,5", "5 is given twice; give each team size once"),
])
def test_bad_team_sizes_say_what_to_give(text: str, problem: str) -> None:
    with pytest.raises(ValueError) as raised:
        team_sizes(text)
    assert str(raised.value) == problem


@pytest.mark.parametrize("text", ["tcp://10.0.0.5:8786", "10.0.0.5:8786", "tls://scheduler.lab:443",
                                  "tcp://[::1]:8786", "localhost:1"])
def test_scheduler_addresses_are_dask_addresses(text: str) -> None:
    assert scheduler_address(text) == text


@pytest.mark.parametrize("text", ["bogus", "tcp://host", "tcp://:8786", "http://host:8786", "host:0", "host:65536",
                                  "host:port", ""])
def test_bad_scheduler_addresses_say_what_to_give(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError) as raised:
        scheduler_address(text)
    assert str(raised.value) == (f"{text!r}: give the scheduler's address as [tcp|tls|ws|wss|ucx://]HOST:PORT "
                                 "with a port 1-65535, e.g. tcp://10.0.0.5:8786")


@pytest.mark.processes
@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["simulate", "no-such-scenario"], "ringtrack: error: scenario 'no-such-scenario' is neither a file nor a"),
        (["simulate", "--robots", "2"], "ringtrack: error: --robots 2 (team.robots): expected `int` >= 3; fix the value"),
        (["simulate", "--drop", "1.5"], "ringtrack: error: --drop 1.5 (faults.drop): expected a probability in [0, 1]"),
        (["simulate", "--steps", "0"], "ringtrack: error: argument --steps: 0 is below 1; give an integer >= 1"),
        (["spawn", "--rate", "0"], "ringtrack: error: argument --rate: '0' is not a positive number; give e.g. 1"),
        (["spawn", "--rate", "nan"], "ringtrack: error: argument --rate: 'nan' is not a positive number"),
        (["spawn", "--robots", "100000"], "ringtrack: error: --robots 100000: 100000 robot processes of about 80 MiB"),
        (["spawn", "--strategy", "often"], "ringtrack: error: --strategy often: 'often' is not a registered strategy nor a "
         "Python file; give one of belief, constant, plan, relay, self or the path of a .py file that defines a Strategy"),
        (["plot", "log.jsonl", "-o", "figure.xyz"], "ringtrack: error: argument -o/--output: 'figure.xyz': give a file"),
        (["experiment", "moving", "--seed", "-1"], "ringtrack: error: argument --seed: -1 is below 0; give an integer"),
        (["experiment", "stationary", "--json", "/dev/null/y.json"], "ringtrack: error: argument --json: '/dev/null/y.json'"),
        (["world", "--listen", "localhost"], "ringtrack: error: --listen 'localhost' is not an endpoint;"),
        (["robot", "--id", "9"], "ringtrack: error: --id 9: the team has robots 0..5"),
        (["spawn", "--robots-per-process", "0"], "ringtrack: error: argument --robots-per-process: 0 is below 1"),
        (["bench", "latency", "--rounds", "0"], "ringtrack: error: argument --rounds: 0 is below 1"),
        (["bench", "engine", "--sweep", "2-5"], "ringtrack: error: --sweep '2-5': every team needs at least 3"),
        (["experiment", "moving", "--cluster", "bogus"], "ringtrack: error: argument --cluster: 'bogus': give the "
         "scheduler's address as [tcp|tls|ws|wss|ucx://]HOST:PORT"),
        (["experiment", "stationary", "--robots", "6-3"], "ringtrack: error: argument --robots: --robots '6-3': 6-3 "
         "is no range; give FIRST-LAST[:STEP], FIRST <= LAST, STEP >= 1, e.g. 3-30:3"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(arguments: list[str], message: str) -> None:
    completed = subprocess.run([sys.executable, "-m", "ringtrack.tools.cli", *arguments], capture_output=True, text=True,
                               timeout=60)
    assert completed.returncode == 2
    lines = completed.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message), completed.stderr


def test_moving_experiment_json_and_figures(tmp_path: Path) -> None:
    data, figure = tmp_path / "m.json", tmp_path / "m.png"
    assert main(["experiment", "moving", "--workers", "1", "--trials", "2", "--steps", "120", "--settle", "20",
                 "--json", str(data), "--plot", str(figure)]) == 0
    result = json.loads(data.read_text())
    comparison = [run for run in result["runs"] if run["group"] == "comparison"]
    assert [(run["strategy"], run["estimation"]) for run in comparison] == [
        ("constant", "centralized"), ("self", "centralized"), ("self", "decentralized")]
    assert {(run["speed"], run["angular_speed"]) for run in comparison} == {(1.0, 0.6)}
    settings = {(run["speed"], run["angular_speed"]) for run in result["runs"] if run["group"] == "velocities"}
    assert settings == {(0.6, 0.6), (1.0, 0.6), (1.0, 0.4), (1.0, 0.8)}
    for run in result["runs"]:
        assert len(run["cerr_series_deg"]) == len(run["terr_series"]) == 120 // result["series_stride"]
        assert run["robot_messages_per_step"] == pytest.approx(4 * 6 * run["poll_rate"])
    constant = comparison[0]
    assert constant["poll_rate"] == 1.0 and constant["estimation_messages_per_step"] == 7
    # the fields of experiment tracking's rows: Terr over the scenario's own strategy's centralized
    # run at the same velocity, else the first centralized run there
    reference: dict[tuple[float, float], float] = {}
    for run in sorted(result["runs"], key=lambda run: run["strategy"] != "self"):
        if run["estimation"] == "centralized":
            reference.setdefault((run["speed"], run["angular_speed"]), run["terr_mean"])
    assert reference[1.0, 0.6] == comparison[1]["terr_mean"]
    for run in result["runs"]:
        assert run["scenario"] == "gazebo-moving"
        assert run["terr_ratio"] == pytest.approx(run["terr_mean"] / reference[run["speed"], run["angular_speed"]])
        assert run["robot_messages_per_robot_step"] >= 0
    for path in (figure, tmp_path / "m-velocities.png"):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.processes
def test_moving_experiment_needs_a_circling_target() -> None:
    completed = subprocess.run([sys.executable, "-m", "ringtrack.tools.cli", "experiment", "moving", "paper-stationary"],
                               capture_output=True, text=True, timeout=60)
    assert completed.returncode == 2
    assert completed.stderr.strip() == "ringtrack: error: paper-stationary.toml: experiment moving needs target.motion = 'circle'"


@pytest.mark.processes
def test_a_table_written_to_a_pipe_is_never_cut() -> None:
    """Off a terminal a table takes the width it needs, however narrow the console says it is: every
    column is there (the drop rate first) and no cell ends in an ellipsis."""
    completed = subprocess.run([sys.executable, "-m", "ringtrack", "experiment", "faults", "paper-stationary",
                                "--drop", "0,0.3", "--trials", "2", "--steps", "60"],
                               capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "40"})
    assert completed.returncode == 0, completed.stderr
    lines = completed.stdout.splitlines()
    header = next(line for line in lines if "strategy" in line)
    assert header.split() == ["drop", "outage", "r_c", "strategy", "done", "Ctime", "Com-bar", "msgs", "J/robot"]
    assert "…" not in completed.stdout
    assert any(line.split()[:4] == ["0.3", "0", "-", "constant"] for line in lines)


def test_show_widens_a_table_only_off_a_terminal() -> None:
    """:func:`show` prints a table wider than a pipe's console whole, and at a terminal's width on one."""
    table = Table("a column with a long heading", "another column with a long heading")
    table.add_row("a cell that is long enough to be cut", "and another one")
    piped = Console(file=io.StringIO(), width=30)
    show(table, piped)
    assert "…" not in piped.file.getvalue() and "a cell that is long enough to be cut" in piped.file.getvalue()
    terminal = Console(file=io.StringIO(), width=30, force_terminal=True, color_system=None)
    show(table, terminal)
    assert max(len(line) for line in terminal.file.getvalue().splitlines()) <= 30
