"""The live dashboard, replay and plot (tools/dashboard.py, tools/views.py, tools/replay.py, tools/plot.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from rich.console import Console

from bus.counting import totals_by_category
from tools.cli import main
from tools.dashboard import Dashboard, TeamModel, reason_text, sparkline
from tools.runlog import read_log
from tools.spawn import spawn_team
from tools.views import LiveView
from world.scenario import load_scenario

pytestmark = pytest.mark.timeout(240)


def render(model: TeamModel, width: int = 120, height: int = 50) -> str:
    console = Console(record=True, width=width, height=height, force_terminal=False, color_system=None)
    console.print(Dashboard(model))
    return console.export_text()


def prepared_records(robots: int = 4, steps: int = 3) -> list[dict]:
    """Hand-made step records: robot 1 polls every step (2 requests, and replies from 0 and 2)."""
    scenario = load_scenario("paper-stationary", robots=robots)
    positions = scenario.start_positions(0).tolist()
    target = scenario.target.tolist()
    records = []
    for step in range(1, steps + 1):
        records.append({
            "type": "step", "step": step, "time": 0.1 * (step - 1), "positions": positions, "target": target,
            "live": list(range(robots)), "trigger": [0, 1, 0, 0][:robots], "offset": [0.01] * robots,
            "ages": [[step, step]] * robots, "centre": [target] * robots,
            "sent_messages": [1, 2, 1, 0], "sent_bytes": [40, 36, 40, 0],
            "received_messages": [1, 2, 1, 0], "received_bytes": [18, 80, 18, 0],
            "traffic": {"robot": [4, 116], "world": [2 * robots + 1, 500], "estimation": [0, 0]},
        })
    return records


def test_dashboard_shows_robots_traffic_and_saved_messages() -> None:
    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    for record in prepared_records():
        model.add(record)
    text = render(model)
    assert "step 3/3000" in text and "4 robots" in text and "lockstep" in text
    for robot in range(4):
        assert re.search(rf"^\s*r{robot} {robot}\s+up\s", text, re.MULTILINE), text
    row = re.search(r"^\s*r1 1\s+up.*$", text, re.MULTILINE).group(0)
    assert " 3 " in row and "6/108" in row and "6/240" in row and "T1 ubd @3" in row  # polls, sent, recv, reason
    assert re.search(r"robot-to-robot\s+12\s+348\s", text)
    assert re.search(r"world\s+27\s+1500\s", text)
    # the constant strategy would have sent 4 robots x 4 messages x 3 steps = 48: 36 saved (75 %)
    assert "saved vs constant: 36 robot-to-robot messages (75%), polls 3" in text
    assert "Cerr " in text and "Terr" not in text  # a known target has no estimation error


def test_dashboard_adapts_to_the_console_and_marks_dead_robots() -> None:
    model = TeamModel(load_scenario("paper-stationary", robots=4), "realtime")
    records = prepared_records()
    records[-1] = {**records[-1], "live": [0, 2, 3], "trigger": [0, None, 0, 0], "ages": [[3, 3], None, [3, 3], [3, 3]]}
    for record in records:
        model.add(record)
    for width, height in ((60, 20), (100, 30), (160, 60)):
        text = render(model, width, height)
        assert re.search(r"r1 1\s+down", text), (width, height)
        assert all(len(line) <= width for line in text.splitlines())


def test_helpers() -> None:
    assert reason_text(1 | 4) == "T1 ubd, T3 order-" and reason_text(16) == "start" and reason_text(0) == "-"
    assert str(sparkline([0.0, 1.0, 2.0, 3.0], 10)) == "▁▃▆█"
    assert str(sparkline([5.0, 5.0], 10)) == "▁▁"


def test_lines_without_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    console = Console(force_terminal=False, width=200)
    with LiveView(console, model, dashboard=False) as view:
        for record in prepared_records():
            model.add(record)
            view.refresh()
        view.refresh(final=True)
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("step 1/3000: robot-to-robot 4 msgs 116 B (saved 12 = 75% vs constant)")
    assert lines[-1].startswith("step 3/3000: robot-to-robot 12 msgs 348 B (saved 36 = 75% vs constant), world 27 msgs")


def test_dashboard_of_a_real_run_equals_the_monitor(tmp_path: Path) -> None:
    scenario = load_scenario("paper-stationary", max_steps=80)
    result = spawn_team(scenario, runs=tmp_path, dashboard=True, quiet=True)
    assert result["exit_code"] == 0
    folder = Path(result["folder"])
    live = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", (folder / "monitor.stdout").read_text())  # drop ANSI codes
    assert "ringtrack paper-stationary · 6 robots" in live and "saved vs constant" in live
    log = read_log(folder / "log.jsonl")
    model = TeamModel(log.scenario, "lockstep")
    for record in log.steps:
        model.add(record)
    seen = totals_by_category([tuple(row) for row in log.end["traffic"]])
    assert model.totals["robot"] == [seen["robot"]["messages"], seen["robot"]["bytes"]]
    end_message = 1  # the End is the one world message not stamped with a step
    assert model.totals["world"][0] == seen["world"]["messages"] - end_message
    text = render(model)
    saved = 4 * 6 * 80 - seen["robot"]["messages"]
    assert f"saved vs constant: {saved} robot-to-robot messages" in text
    assert "step 80/80" in text or "step 80/" in text
    for robot in range(6):
        sent = sum(record["sent_messages"][robot] for record in log.steps)
        assert re.search(rf"^\s*r{robot} {robot}\s+up.*\s{sent}/\d+\s", text, re.MULTILINE)


def test_summary_lines_when_the_monitor_has_no_terminal(tmp_path: Path) -> None:
    result = spawn_team(load_scenario("paper-stationary", max_steps=40), runs=tmp_path, quiet=True)
    lines = (Path(result["folder"]) / "monitor.stdout").read_text().splitlines()
    steps = [line for line in lines if line.startswith("step ")]
    assert steps and steps[-1].startswith("step 40/40: robot-to-robot")


def test_replay_and_plot_of_an_engine_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log, figure = tmp_path / "run.jsonl", tmp_path / "run.png"
    assert main(["simulate", "authors-moving", "--estimation", "centralized", "--steps", "60", "--log", str(log)]) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--speed", "1e9", "--no-dashboard"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("step 60/60: robot-to-robot") and "Terr" in lines[-1]
    assert main(["replay", str(log), "--final"]) == 0
    final = capsys.readouterr().out
    assert "step 60/60" in final and "centralized target" in final and "Terr" in final and "replay" not in final
    assert main(["plot", str(log), "-o", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_replay_of_a_killed_run_and_bad_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "run.jsonl"
    assert main(["simulate", "--steps", "30", "--log", str(log)]) == 0
    lines = log.read_bytes().splitlines(keepends=True)
    log.write_bytes(b"".join(lines[:-2]) + lines[-2][:25])  # no end record, a torn last line
    capsys.readouterr()
    assert main(["replay", str(log), "--speed", "1e9", "--dashboard"]) == 0
    assert "log ends here (the run was stopped)" in capsys.readouterr().out
    assert main(["replay", str(tmp_path / "missing.jsonl")]) == 2
    (tmp_path / "not-a-log.jsonl").write_text('{"type": "step"}\n')
    assert main(["plot", str(tmp_path / "not-a-log.jsonl"), "-o", str(tmp_path / "x.png")]) == 2
    assert "no header record; this is not a ringtrack run log" in capsys.readouterr().err
