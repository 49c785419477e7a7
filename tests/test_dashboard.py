"""The live dashboard, replay and plot (tools/dashboard/dashboard.py, tools/dashboard/views.py, tools/dashboard/replay.py, tools/runlog/plot.py)."""

from __future__ import annotations

import io
import re
import time
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from ringtrack.agents.laws import Trigger, reason_text
from ringtrack.bus.counting import totals_by_category
from ringtrack.tools.cli import main
from ringtrack.tools.dashboard.dashboard import Dashboard, sparkline
from ringtrack.tools.dashboard.views import LiveView
from ringtrack.tools.monitor.state import TeamModel
from ringtrack.tools.runlog.log import LogWriter, RunLog, read_log
from ringtrack.tools.runlog.plot import PANELS, plot_run
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario
from tests.helpers import lockstep_run

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
        assert re.search(rf"(?:^|\s)r{robot} {robot}\s+ok\|ok\s", text, re.MULTILINE), text
    row = re.search(r"(?:^|\s)r1 1\s+ok\|ok.*$", text, re.MULTILINE).group(0)
    assert " 3 " in row and "6/108" in row and "6/240" in row and "T1 @3" in row  # polls, sent, recv, reason
    assert re.search(r"robot-to-robot\s+12\s+348\s", text)
    assert re.search(r"world\s+27\s+1500\s", text)
    # the constant strategy would have sent 4 robots x 4 messages x 3 steps = 48: 36 saved (75 %)
    assert "Com-bar 0.250 so far (constant 1) · saved 36 msgs (75%) vs constant · polls 3" in text
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
        assert re.search(r"r0 0\s+ok\|gone", text) and re.search(r"r2 2\s+gone\|ok", text), (width, height)
        assert all(len(line) <= width for line in text.splitlines())


def test_helpers() -> None:
    assert reason_text(1 | 4) == "T1+T3" and reason_text(16) == "start" and reason_text(0) == "-"
    assert reason_text(1 | 2 | 4 | 32) == "T1+T2+T3+unk" and reason_text(8) == "every"
    assert str(sparkline([0.0, 1.0, 2.0, 3.0], 10)) == "▁▃▆█"
    assert str(sparkline([5.0, 5.0], 10)) == "▁▁"


def test_lines_without_a_terminal() -> None:
    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    stream = io.StringIO()
    console = Console(file=stream, force_terminal=False, width=200)
    first, *others = prepared_records()
    with LiveView(console, model, dashboard=False) as view:
        model.add(first)
        view.refresh()
        deadline = time.monotonic() + 5.0
        while not stream.getvalue() and time.monotonic() < deadline:  # the drawer thread writes it
            time.sleep(0.01)
        for record in others:  # within LINE_PERIOD_S of the first line: no line
            model.add(record)
            view.refresh()
        view.refresh(final=True)
    lines = stream.getvalue().strip().splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("step 1/3000: robot-to-robot 4 msgs 116 B (saved 12 = 75% vs constant)")
    assert lines[-1].startswith("step 3/3000: robot-to-robot 12 msgs 348 B (saved 36 = 75% vs constant), world 27 msgs")


def final_frame(text: str, header: str) -> str:
    """The last frame a live dashboard wrote (ANSI codes dropped), from its last ``header`` on."""
    plain = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", text)
    assert header in plain, plain[-2000:]
    return plain[plain.rindex(header):]


@pytest.mark.processes
def test_dashboard_of_a_real_run_equals_the_monitor(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "120")  # the monitor's forced terminal: wide enough for every column
    monkeypatch.setenv("LINES", "60")
    scenario = load_scenario("paper-stationary", max_steps=80)
    result = spawn_team(TeamPlan(scenario=scenario, runs=tmp_path, dashboard=True, quiet=True))
    assert result.exit_code == 0
    folder = Path(result.folder)
    log = read_log(folder / "log.jsonl")
    end = log.end
    assert end is not None and end["late"] == 0 and end["consistent"] is True
    rows = [tuple(row) for row in end["traffic"]]
    seen = totals_by_category(rows)

    # The live dashboard's own last frame shows the monitor's totals of the end record ...
    frame = final_frame((folder / "monitor.stdout").read_text(), "paper-stationary · 6 robots")
    heading = frame[:frame.index("traffic")]  # the header line, wrapped perhaps
    assert "step 80/80" in heading and "done" in heading
    robot = seen["robot"]
    assert re.search(rf"robot-to-robot\s+{robot['messages']}\s+{robot['bytes']}\s", frame), frame
    # ... less the End, the one world message not stamped with a step
    world = totals_by_category([row for row in rows if row[0] != "end"])["world"]
    assert re.search(rf"world\s+{world['messages']}\s+{world['bytes']}\s", frame), frame
    saved = 4 * 6 * 80 - robot["messages"]
    assert f"saved {saved} msgs" in frame
    for index in range(6):
        name = f"r{index}"
        sent = [sum(row[k] for row in rows if row[0] in ("request", "reply") and row[1] == name) for k in (3, 4)]
        received = [sum(row[k] for row in rows if row[0] in ("request", "reply") and row[2] == name) for k in (3, 4)]
        assert re.search(rf"(?:^|\s){name} {index}\s+ok\|ok\s.*\s{sent[0]}/{sent[1]}\s+{received[0]}/{received[1]}\s",
                         frame, re.MULTILINE), frame

    # and a model rebuilt from the log shows the same.
    model = TeamModel(log.scenario, "lockstep")
    for record in log.records:
        model.add(record)
    assert model.totals["robot"] == [robot["messages"], robot["bytes"]]
    assert model.totals["world"] == [world["messages"], world["bytes"]]


@pytest.mark.processes
def test_summary_lines_when_the_monitor_has_no_terminal(tmp_path: Path) -> None:
    result = spawn_team(TeamPlan(scenario=load_scenario("paper-stationary", max_steps=40), runs=tmp_path, quiet=True))
    lines = (Path(result.folder) / "monitor.stdout").read_text().splitlines()
    steps = [line for line in lines if line.startswith("step ")]
    assert steps and steps[-1].startswith("step 40/40: robot-to-robot")


def test_replay_and_plot_of_an_engine_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log, figure = tmp_path / "run.jsonl", tmp_path / "run.png"
    assert main(["simulate", "authors-moving", "--estimation", "centralized", "--steps", "60", "--log", str(log)]) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--speed", "1e9", "--no-dashboard"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("step 60/60: robot-to-robot") and "Terr" in lines[-1]
    assert re.match(r"step 60/60: robot-to-robot \d+ msgs - B ", lines[-1])  # the engine counts no bytes
    assert main(["replay", str(log), "--final"]) == 0
    final = capsys.readouterr().out
    assert "step 60/60" in final and "Terr" in final and "replay" not in final
    assert re.search(r"robot-to-robot\s+\d+\s+-\s", final) and re.search(r"world\s+\d+\s+-\s", final)
    assert re.search(r"(?:^|\s)r0 0\s.*\s\d+/-\s", final, re.MULTILINE) and "/0 " not in final and " 0 B" not in final
    assert main(["plot", str(log), "-o", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_long_trigger_reason_leaves_the_other_columns_whole() -> None:
    """Cells as wide as a long run of 64 robots makes them: whole columns, as many rows as fit."""
    robots = 64
    scenario = load_scenario("paper-stationary", robots=robots)
    model = TeamModel(scenario, "lockstep")
    every_condition = int(Trigger.UNCERTAINTY | Trigger.SUCCESSOR | Trigger.PREDECESSOR | Trigger.UNKNOWN)
    target = scenario.target.tolist()
    for step in range(12343, 12346):
        model.add({"type": "step", "step": step, "time": 0.1 * step, "positions": scenario.start_positions(0).tolist(),
                   "target": target, "live": list(range(robots)), "trigger": [every_condition] * robots,
                   "offset": [0.01] * robots, "ages": [[999, 999]] * robots, "centre": [target] * robots,
                   "sent_messages": [33333] * robots, "sent_bytes": [3333333] * robots,
                   "received_messages": [33333] * robots, "received_bytes": [3333333] * robots,
                   "traffic": {"robot": [4, 116], "world": [2 * robots + 1, 500], "estimation": [0, 0]}})
    for robot in range(robots):
        model.add(fault(12345, "dropped", robot, (robot + 1) % robots, "outage"))
    for width, height, columns in ((80, 24, 6), (100, 30, 6), (160, 60, 10)):
        text = render(model, width, height)
        rows = re.findall(r"\br\d+ \w  +outage\|outage .*$", text, re.MULTILINE)
        assert len(rows) == height - 2 - 6 - 2 - 1, text  # header, legend; traffic and figures; table head; "more"
        assert f"… and {robots - len(rows)} more robots (r{len(rows)}-r63)" in text
        assert not any("…" in row for row in rows), text
        cells = [row.split() for row in rows]
        assert all(len(row) == columns + 2 for row in cells), rows  # "r0 0", "T1+... @12345": two words
        assert all(re.search(r" outage\|outage .*T1\+T2\+T3\+unk @12345 *$", row) for row in rows), rows


def fault(step: int, what: str, sender: int, receiver: int, reason: str | None = None) -> dict:
    """A fault event record as the monitor logs a FaultNotice."""
    return {"type": "event", "event": what, "step": step, "subject": "request", "sender": sender,
            "receiver": receiver, "reason": reason, "delay_s": 0.05 if what == "delayed" else None}


def link_cells(text: str) -> dict[int, str]:
    """Robot index -> its links cell in a rendered dashboard."""
    return {int(index): cell for index, cell in re.findall(r"(?:^|\s)r(\d) \d\s+(\S+)\s", text, re.MULTILINE)}


def test_link_state_shows_recent_faults_on_both_ends_and_gone_neighbours() -> None:
    model = TeamModel(load_scenario("paper-stationary", robots=4), "lockstep")
    steps = prepared_records(steps=12)
    model.add(steps[0])
    model.add(fault(2, "dropped", 1, 2, "outage"))  # noticed before its step record is written
    model.add(steps[1])
    model.add(fault(2, "delayed", 0, 3))
    assert link_cells(render(model)) == {0: "delay|ok", 1: "ok|outage", 2: "outage|ok", 3: "ok|delay"}
    model.add(fault(2, "duplicated", 3, 0))  # the latest fault of a link is the one shown
    for record in steps[2:11]:
        model.add(record)
    assert model.step == 11 and model.link_state(1, 2) == "outage" and model.link_state(3, 0) == "dup"
    model.add({**steps[11], "live": [0, 1, 3], "trigger": [0, None, 0, 0]})  # 10 steps on, and robot 2 gone
    assert link_cells(render(model)) == {0: "ok|ok", 1: "ok|gone", 2: "down", 3: "gone|ok"}


def test_replay_shows_the_link_faults_of_the_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = load_scenario("paper-stationary", robots=4)
    path = tmp_path / "faults.jsonl"
    steps = prepared_records(steps=5)
    with LogWriter(path) as writer:
        writer.header(scenario, "emulator", 1, 0, "lockstep", 5)
        for record in [*steps[:3], fault(4, "dropped", 2, 3, "range"), *steps[3:]]:
            writer.write(record)
    assert main(["replay", str(path), "--final"]) == 0
    final = capsys.readouterr().out
    assert link_cells(final) == {0: "ok|ok", 1: "ok|ok", 2: "ok|range", 3: "range|ok"}
    assert main(["replay", str(path), "--speed", "1e9", "--dashboard"]) == 0
    assert link_cells(final_frame(capsys.readouterr().out, "paper-stationary · 4 robots")) == link_cells(final)


def robot_links(log: RunLog) -> dict[str, tuple[int, int]]:
    """Robot-to-robot (messages, bytes) per "source>destination" link of the log's end record."""
    links: dict[str, tuple[int, int]] = {}
    for kind, source, destination, messages, size in log.end["traffic"]:
        if kind in ("request", "reply"):
            before = links.get(f"{source}>{destination}", (0, 0))
            links[f"{source}>{destination}"] = (before[0] + messages, before[1] + (size or 0))
    return links


def check_figure(log: RunLog) -> None:
    """The four panels of ``plot_run`` show what the log holds."""
    figure = plot_run(log)
    titled = {axes.get_title(): axes for axes in figure.axes if axes.get_title()}
    assert len(titled) == 4 and PANELS[0] in titled and PANELS[1] in titled and PANELS[3] in titled
    polls = sum(1 for record in log.steps for trigger in record["trigger"] if trigger)
    assert f"{PANELS[2]} ({polls} in all)" in titled

    robots, positions = log.scenario.robots, np.array([record["positions"] for record in log.steps])
    paths = {line.get_label(): line for line in titled[PANELS[0]].get_lines() if re.fullmatch(r"r\d+", line.get_label())}
    assert sorted(paths) == sorted(f"r{robot}" for robot in range(robots))
    for robot in range(robots):
        assert np.array_equal(paths[f"r{robot}"].get_xydata(), positions[:, robot])

    series = {line.get_label(): line for axes in figure.axes for line in axes.get_lines()}
    targets = np.array([record["target"] for record in log.steps])
    assert np.array_equal(series["true target"].get_xydata(), targets)  # on top of every path
    assert series["true target"].get_zorder() > max(line.get_zorder() for name, line in series.items()
                                                    if name != "true target" and not name.startswith("true target"))
    assert all(axes.get_xlabel() for axes in figure.axes if axes.get_title())  # every panel's axes say what
    assert titled[PANELS[0]].get_xlabel() == "x (m)" and titled[PANELS[0]].get_ylabel() == "y (m)"
    moving = log.scenario.moving
    assert any(name.startswith("Ctime threshold") for name in series) != moving  # none for a moving target
    legend_texts = [text.get_text() for axes in figure.axes if axes.get_legend()
                    for text in axes.get_legend().get_texts()]
    assert ("Terr (right axis)" in legend_texts) == (log.scenario.estimation.mode != "known")
    assert len(series["Cerr, true positions"].get_ydata()) == len(log.steps)
    assert len(series["Cerr, robots' memory"].get_ydata()) == len(log.steps)
    if log.scenario.estimation.mode == "known":
        assert not any(label.startswith("Terr") for label in series)
    else:
        assert len(series["Terr (right axis)"].get_ydata()) == len(log.steps)

    expected = robot_links(log)
    bars = {container.get_label(): container for axes in figure.axes for container in axes.containers}
    names = [label.get_text() for label in titled[PANELS[3]].get_xticklabels()]
    assert names == sorted(expected, key=lambda name: [int(part[1:]) for part in name.split(">")])
    assert [bar.get_height() for bar in bars["messages"]] == [expected[name][0] for name in names]
    if log.header["source"] == "engine":
        assert "bytes" not in bars
    else:
        assert [bar.get_height() for bar in bars["bytes"]] == [expected[name][1] for name in names]


@pytest.mark.processes
def test_plot_of_a_lockstep_run_and_of_an_engine_log(tmp_path: Path) -> None:
    _, log = lockstep_run(load_scenario("paper-stationary", max_steps=60), tmp_path / "team")
    assert len(log.steps) == 60 and sum(robot_links(log)[name][1] for name in robot_links(log)) > 0
    check_figure(log)
    path = tmp_path / "engine.jsonl"
    assert main(["simulate", "authors-moving", "--estimation", "centralized", "--steps", "40", "--log", str(path)]) == 0
    engine_log = read_log(path)
    assert engine_log.header["source"] == "engine" and len(engine_log.steps) == 40
    check_figure(engine_log)


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


def engine_model(scenario_name: str, robots: int, steps: int, **overrides: object) -> TeamModel:
    """A dashboard model fed with an engine run's step records."""
    from ringtrack.agents import engine
    from ringtrack.tools.runlog.log import history_from_log, write_engine_log

    scenario = load_scenario(scenario_name, robots=robots, max_steps=steps, **overrides)
    path = Path(f"/tmp/ringtrack-dashboard-{scenario_name}-{robots}-{steps}-{id(scenario)}.jsonl")
    try:
        write_engine_log(path, engine.run(scenario, record_positions=True))
        log = read_log(path)
    finally:
        path.unlink(missing_ok=True)
    assert history_from_log(log).steps == steps
    model = TeamModel(log.scenario, "lockstep")
    for record in log.records:
        model.add(record)
    return model


@pytest.mark.parametrize("width,height", [(80, 24), (100, 30), (160, 50)])
def test_every_size_shows_one_line_per_robot_a_legend_and_an_unwrapped_header(width: int, height: int) -> None:
    model = engine_model("authors-moving", 6, 40, estimation="decentralized")
    text = render(model, width, height)
    lines = text.splitlines()
    assert len(lines) <= height and all(len(line) <= width for line in lines), (width, height)
    assert "authors-moving" in lines[0] and "step 40/40" in lines[0] and "running" in lines[0]  # one header line
    assert "step 40/40" not in "\n".join(lines[1:])
    for robot in range(6):  # every robot's row, whole
        row = rf"\br{robot} {robot}  +ok\|ok +\d+\.\d° .*(T\d|start)[+\w]* @\d+ *$"
        assert re.search(row, text, re.MULTILINE), text
    assert "Com-bar " in text and "so far (constant 1)" in text and "Cerr " in text and "Terr " in text
    legend = lines[-1]
    assert "T1 ubd" in legend and "T2" in legend and "T3" in legend and "ubd" in legend
    if width >= 100:
        assert "gV guaranteed midpoint" in legend and "ages" in legend
    if width != 100:  # at 100 columns the entries of gV and ages take the room
        assert "x target" in legend


def map_extent(text: str) -> tuple[int, int]:
    """(columns, rows) the map's boundary dots span in a rendered dashboard (the block left of the
    traffic table)."""
    lines = text.splitlines()[1:-1]
    left = lines[0].index("traffic")
    dots = [(row, column) for row, line in enumerate(lines) for column, character in enumerate(line[:left])
            if character == "·"]
    rows, columns = {row for row, _ in dots}, {column for _, column in dots}
    return max(columns) - min(columns) + 1, max(rows) - min(rows) + 1


@pytest.mark.parametrize("width,height", [(80, 24), (100, 30), (160, 50)])
def test_the_map_keeps_the_region_aspect_on_two_to_one_cells(width: int, height: int) -> None:
    model = engine_model("paper-stationary", 6, 20)
    vertices = model.scenario.region.vertices
    aspect = np.ptp(vertices[:, 1]) / np.ptp(vertices[:, 0])  # 19 m tall, 7 m wide
    columns, rows = map_extent(render(model, width, height))
    assert rows >= height - 4  # a tall region takes the height
    assert abs((rows / columns) / (aspect / 2.0) - 1.0) < 0.2, (columns, rows)


def test_a_large_team_at_80x24_lists_as_many_robots_as_fit() -> None:
    model = engine_model("paper-stationary", 64, 20)
    text = render(model, 80, 24)
    rows = re.findall(r"\br(\d+) \w  +ok\|ok ", text)
    side = 4 + 2  # the traffic table (head, rule, two rows), Com-bar, Cerr
    assert [int(robot) for robot in rows] == list(range(24 - 2 - side - 2 - 1))  # header, legend; head; "more"
    assert f"… and {64 - len(rows)} more robots (r{len(rows)}-r63)" in text


def test_the_start_up_frame_says_who_is_up() -> None:
    model = TeamModel(load_scenario("paper-stationary"), "lockstep")
    model.expected = ["world", "monitor", *(f"r{robot}" for robot in range(6))]
    model.up = {"world", "monitor", "r0", "r3"}
    text = render(model, 80, 24)
    assert "starting" in text.splitlines()[0] and "4/8 participants up" in text
    assert "up: world monitor r0 r3" in text and "waiting for: r1 r2 r4 r5" in text
    assert model.summary_line() == "starting: 4/8 participants up"
