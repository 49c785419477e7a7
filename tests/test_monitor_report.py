"""The monitor's verdict and end-of-run report (tools/monitor/monitor.py MonitorReport, tools/dashboard/views.py
print_report), and the records it hands the dashboard (tools/monitor/monitor.py Recorder)."""

from __future__ import annotations

import re

from rich.console import Console

from ringtrack.bus.keys import Route
from ringtrack.bus.messages import SCHEMA, FaultNotice
from ringtrack.bus.participant import Delivery
from ringtrack.tools.dashboard.views import print_report
from ringtrack.tools.monitor.monitor import MonitorReport, Recorder
from ringtrack.tools.monitor.state import TeamModel
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
    from ringtrack.tools.dashboard.views import per_link_table, per_robot_table

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


def test_a_digest_counts_robot_to_robot_traffic_by_the_commanding_robots_own_counts() -> None:
    from types import SimpleNamespace

    from ringtrack.bus.counting import TrafficCounter
    from ringtrack.bus.keys import Keys
    from ringtrack.bus.messages import Command, Digest, DigestEntry, Tick
    from ringtrack.tools.monitor.monitor import digested, monitored_keys

    scenario = load_scenario("paper-stationary", robots=3)
    written = Written()
    recorder = Recorder(written, scenario)  # type: ignore[arg-type]
    monitor = SimpleNamespace(counter=TrafficCounter())
    tick = Tick(SCHEMA, 1, 1, 0.0, [(0.0, 0.0)] * 3, (1.0, 1.0), [0, 1, 2])
    # r1 polled both neighbours: its request to r2 went out twice (duplicated), so r2 answered twice;
    # r0 and r2 only commanded.
    polled = Command(SCHEMA, 1, 1, 1, (0.0, 0.0), 1, 0.0, (0, 0), (1.0, 1.0), None,
                     [(0, 0, 1, 17), (1, 0, 1, 38), (0, 2, 2, 18), (1, 2, 2, 39)])
    quiet = [Command(SCHEMA, 1, 1, robot, (0.0, 0.0), 0, 0.0, (3, 3), (1.0, 1.0)) for robot in (0, 2)]
    entry = DigestEntry(1, tick, [(0, 70), (1, 70), (2, 70)], [(polled, 90), (quiet[0], 64), (quiet[1], 64)])
    digested(monitor, recorder, Digest(SCHEMA, 1, [entry]))  # type: ignore[arg-type]
    recorder.flush()
    (record,) = written  # the step's tick came in the digest
    assert record["positions"] == [[0.0, 0.0]] * 3 and record["traffic"]["world"] == [6, 3 * 70 + 90 + 2 * 64]
    assert record["sent_messages"] == [1, 3, 2] and record["sent_bytes"] == [38, 17 + 2 * 18, 2 * 39]
    assert record["received_messages"] == [1, 3, 2] and record["received_bytes"] == [17, 38 + 2 * 39, 2 * 18]
    assert record["traffic"]["robot"] == [6, 17 + 38 + 2 * 18 + 2 * 39]
    rows = {row[:3]: row[3:] for row in monitor.counter.received_table()}
    assert rows[("request", "r1", "r2")] == (2, 36) and rows[("reply", "r2", "r1")] == (2, 78)
    assert rows[("request", "r1", "r0")] == (1, 17) and rows[("reply", "r0", "r1")] == (1, 38)
    # Fed by digests, the monitor subscribes to no kind a digest accounts for; auditing, to everything.
    keys = Keys(1)
    kinds = {key.rsplit("/", 1)[-1] for key in monitored_keys(keys, digests=True)}
    assert not kinds & {"measurement", "command", "request", "reply", "push"} and {"tick", "digest", "stats"} <= kinds
    assert monitored_keys(keys, digests=False) == (keys.everything,)


def test_a_step_is_written_only_once_the_measurements_behind_its_commands_are_in() -> None:
    """A command travels on its robot's link, the measurement it answers on the world's: on a loaded
    machine the command can reach the monitor first. The step waits for both, so nothing is late."""
    from ringtrack.bus.messages import Command, Measurement, Tick

    scenario = load_scenario("paper-stationary", robots=3)
    written = Written()
    recorder = Recorder(written, scenario)  # type: ignore[arg-type]

    def deliver(message, source: str, kind: str) -> None:
        recorder.on_delivery(Delivery(message, Route(source, "monitor", kind), 50))
        recorder.flush()

    deliver(Tick(SCHEMA, 1, 1, 0.0, [(0.0, 0.0)] * 3, (1.0, 1.0), [0, 1, 2]), "world", "tick")
    for robot in range(3):
        deliver(Command(SCHEMA, 1, 1, robot, (0.0, 0.0), 0, 0.0, (3, 3), (1.0, 1.0)), f"r{robot}", "command")
    for robot in range(3):
        assert written == []  # r{robot}'s measurement is still on its way
        deliver(Measurement(SCHEMA, 1, 1, 0.0, robot, (0.0, 0.0), 1.0), "world", "measurement")
    (record,) = written
    assert record["traffic"]["world"] == [6, 6 * 50] and recorder.late == 0


def test_a_robot_the_world_takes_out_of_its_live_set_is_cut_off_for_the_books() -> None:
    """A robot silent past the lockstep wait leaves the world's live set without losing its alive
    token: the recorder notes it from the ticks, and a reply it sends its neighbour after that
    neighbour stopped waiting (counted by the sender, never by the requester) is in flight, not
    unexplained."""
    from ringtrack.bus.counting import close_books
    from ringtrack.bus.messages import Tick

    scenario = load_scenario("paper-stationary", robots=4)
    recorder = Recorder(Written(), scenario)  # type: ignore[arg-type]
    for step, live in ((1, [0, 1, 2, 3]), (2, [0, 1, 2]), (3, [0, 1, 2, 3])):
        recorder.on_tick(Tick(SCHEMA, 1, step, 0.1 * step, [(0.0, 0.0)] * 4, (1.0, 1.0), live))
    assert recorder.left_live == {"r3"}
    said, seen = [("reply", "r3", "r2", 5, 195)], [("reply", "r3", "r2", 4, 156)]
    books = close_books(said, seen, recorder.left_live, ("robot",))
    assert books.balanced and books.in_flight == {("reply", "r3", "r2"): 1}
    assert not close_books(said, seen, set(), ("robot",)).balanced
