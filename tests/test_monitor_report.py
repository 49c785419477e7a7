"""The monitor's verdict and end-of-run report (tools/monitor.py MonitorReport, tools/views.py
print_report), and the records it hands the dashboard (tools/monitor.py Recorder)."""

from __future__ import annotations

import re

from rich.console import Console

from ringtrack.bus.keys import Route
from ringtrack.bus.messages import SCHEMA, FaultNotice
from ringtrack.bus.participant import Delivery
from ringtrack.tools.dashboard import TeamModel
from ringtrack.tools.monitor import MonitorReport, Recorder
from ringtrack.tools.views import print_report
from ringtrack.world.scenario import load_scenario

# What three robots of a ring sent: requests and replies on four links, world and estimation traffic.
SENT = {
    "r0": [("request", "r0", "r1", 3, 60), ("reply", "r0", "r1", 2, 90), ("command", "r0", "world", 10, 500),
           ("range", "r0", "fusion", 10, 300), ("stats", "r0", "monitor", 1, 200)],
    "r1": [("request", "r1", "r0", 2, 40), ("reply", "r1", "r0", 3, 135), ("request", "r1", "r2", 1, 20)],
    "r2": [("reply", "r2", "r1", 1, 45)],
    "world": [("measurement", "world", "r0", 10, 480), ("tick", "world", "all", 10, 900)],
}


def seen_rows(changes: dict[tuple[str, str, str], tuple[int, int]] | None = None) -> list[tuple]:
    """What the monitor saw: every row the senders counted, with the (messages, bytes) of the
    (kind, source, destination) links in ``changes`` replaced or added."""
    links = {(kind, source, destination): (messages, size)
             for rows in SENT.values() for kind, source, destination, messages, size in rows}
    links.update(changes or {})
    return [(*link, *counts) for link, counts in sorted(links.items())]


def report(received: list[tuple]) -> MonitorReport:
    return MonitorReport(received=received, senders=SENT, rejected={}, rss_kib={}, end=None, late=0)


def test_consistent_compares_every_link_not_the_totals() -> None:
    assert report(seen_rows()).consistent()
    # The stats the senders send last are monitoring traffic: not compared.
    assert report(seen_rows({("stats", "r0", "monitor"): (2, 400), ("fault", "r1", "monitor"): (1, 50)})).consistent()
    # One request counted on the wrong link: every category total still equal, the verdict not.
    moved = seen_rows({("request", "r0", "r1"): (2, 40), ("request", "r0", "r2"): (1, 20)})
    assert report(moved).monitor_totals() == report(seen_rows()).monitor_totals()
    assert not report(moved).consistent()
    # The same for a world message on the wrong link, an estimation message of the wrong kind, and bytes.
    for changes in ({("measurement", "world", "r0"): (9, 432), ("measurement", "world", "r1"): (1, 48)},
                    {("range", "r0", "fusion"): (9, 270), ("estimate", "r0", "fusion"): (1, 30)},
                    {("reply", "r2", "r1"): (1, 44), ("reply", "r1", "r0"): (3, 136)}):
        assert report(seen_rows(changes)).monitor_totals() == report(seen_rows()).monitor_totals()
        assert not report(seen_rows(changes)).consistent(), changes


def printed(monitor_report: MonitorReport) -> str:
    console = Console(record=True, width=140, force_terminal=False, color_system=None)
    print_report(console, monitor_report)
    return console.export_text()


def test_report_lists_estimation_traffic_and_every_robot_link() -> None:
    text = printed(report(seen_rows()))
    assert re.search(r"│\s+estimation │\s+10 │\s+300 │\s+10 │\s+300 │\s+30\.0 │", text), text
    links = re.findall(r"│\s+(r\d > r\d) │\s+(\d+)/(\d+) │\s+(\d+)/(\d+) │", text)
    assert links == [("r0 > r1", "5", "150", "5", "150"), ("r1 > r0", "5", "175", "5", "175"),
                     ("r1 > r2", "1", "20", "1", "20"), ("r2 > r1", "1", "45", "1", "45")]
    assert "monitor vs senders: equal on every link" in text

    text = printed(report(seen_rows({("request", "r0", "r1"): (2, 40), ("request", "r0", "r2"): (1, 20)})))
    links = re.findall(r"│\s+(r\d > r\d) │\s+(\d+)/(\d+) │\s+(\d+)/(\d+) │", text)
    assert links[:2] == [("r0 > r1", "4", "130", "5", "150"), ("r0 > r2", "1", "20", "0", "0")]
    assert "monitor vs senders: DIFFERENT" in text


class Written(list):
    """A stand-in for the log writer: keeps the records."""

    def write(self, record: dict) -> None:
        self.append(record)


def test_the_recorder_hands_fault_events_to_the_dashboard() -> None:
    scenario = load_scenario("paper-stationary", robots=4)
    model, written = TeamModel(scenario, "lockstep"), Written()
    recorder = Recorder(written, scenario, model.add)  # type: ignore[arg-type]
    notice = FaultNotice(SCHEMA, 1, step=3, subject="request", sender=1, receiver=2, what="dropped", reason="range",
                         delay_s=0.0)
    recorder.on_delivery(Delivery(notice, Route("monitor", "r1", "fault"), 40))
    assert written == [{"type": "event", "event": "dropped", "step": 3, "subject": "request", "sender": 1,
                        "receiver": 2, "reason": "range", "delay_s": None}]
    assert model.link_state(1, 2) == model.link_state(2, 1) == "range" and model.link_state(0, 1) == "ok"


def test_reports_of_large_teams_are_summarised_unless_all_robots() -> None:
    from ringtrack.tools.views import per_link_table, per_robot_table

    robots = 30
    rows = [("request", f"r{robot}", f"r{(robot + 1) % robots}", robot + 1, 18 * (robot + 1))
            for robot in range(robots)]
    rows += [("measurement", "world", f"r{robot}", 10, 500) for robot in range(robots)]
    console = Console(record=True, width=80, force_terminal=False, color_system=None)
    console.print(per_robot_table(rows))
    text = console.export_text()
    assert re.search(r"│ +min of 30 │ +1/18 │ +1/18 │ +10/500 │", text), text
    assert re.search(r"│ +median of 30 │ +15/270 │", text) and re.search(r"│ +max of 30 │ +30/540 │", text), text
    busiest = re.findall(r"busiest: (r\d+)", text)
    assert busiest == ["r29", "r28", "r27", "r26", "r25"], busiest  # by sent + received: 59, 57, 55, ...
    assert len(re.findall(r"^│", text, re.MULTILINE)) == 3 + 5 and all(len(line) <= 80 for line in text.splitlines())
    console = Console(record=True, width=80, force_terminal=False, color_system=None)
    console.print(per_robot_table(rows, all_robots=True))
    assert len(re.findall(r"^│ +r\d+ │", console.export_text(), re.MULTILINE)) == robots
    # A link where the monitor and the sender differ is shown even in a summary.
    senders = {"r0": [("request", "r0", "r1", 2, 36)]}
    report = MonitorReport(received=rows, senders=senders, rejected={}, rss_kib={}, end=None, late=0)
    console = Console(record=True, width=80, force_terminal=False, color_system=None)
    console.print(per_link_table(report))
    text = console.export_text()
    assert "min of 30" in text and re.search(r"│ +r0 > r1 │ +1/18 │ +2/36 │", text), text


def test_simulate_summarises_the_polls_of_a_large_team(capsys) -> None:
    from ringtrack.tools.cli import main

    assert main(["simulate", "--robots", "25", "--steps", "5"]) == 0
    text = capsys.readouterr().out
    assert "per robot min " in text and "busiest r" in text and "(--all-robots lists all)" in text
    assert all(len(line) <= 80 for line in text.splitlines())
    assert main(["simulate", "--robots", "25", "--steps", "5", "--all-robots"]) == 0
    polls = capsys.readouterr().out
    assert "busiest" not in polls and "Com-bar" in polls and "saved" in polls
