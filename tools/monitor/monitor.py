"""The monitor process: tallies every message and byte of a run live and writes its run log.

It counts what it receives by kind and link (the same :class:`bus.counting.TrafficCounter` the
senders use for what they send): with ``--audit`` every message of the run, by default in lockstep
every kind but those the world's per-step digest accounts for (measurements and commands by the
world's own counts, robot-to-robot messages by the robots' own, :func:`digested`). From the world's
Ticks, the robots' Commands and their requests and replies it assembles one log record per step. When the
world ends the run it waits for every sender's final statistics, checks that its totals equal what
the senders counted, writes the end record and prints a summary.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from ringtrack.bus.config import BusConfig
from ringtrack.bus.counting import Books, close_books, totals_by_category
from ringtrack.bus.faults import DELIVERED, FAULT_COUNTERS, Fate, request_traffic, team_faults
from ringtrack.bus.keys import MONITOR, WORLD, Keys, Route, robot_index, robot_name
from ringtrack.bus.lives import life_label
from ringtrack.bus.messages import (
    KINDS,
    ROBOT_TRAFFIC_KINDS,
    Command,
    Digest,
    DigestEntry,
    End,
    EndReason,
    Estimate,
    FaultNotice,
    Measurement,
    Push,
    RangeReport,
    Reply,
    Request,
    Stats,
    Tick,
    Traffic,
)
from ringtrack.bus.participant import Delivery, Interrupt, Participant, Presence, far_ahead, peak_rss_kib
from ringtrack.bus.runtime import STOPPED, Interrupts, Role, Roster, perform
from ringtrack.tools.monitor.checkpoint import (
    CHECKPOINT_PERIOD_S,
    Checkpoint,
    checkpoint_path,
    read_checkpoint,
    restore_counts,
    write_checkpoint,
)
from ringtrack.tools.monitor.state import TeamModel, startup_names
from ringtrack.tools.runlog.derived import distrust
from ringtrack.tools.runlog.log import LogWriter, step_record
from ringtrack.world.scenario import Scenario

FINAL_STATS_GRACE_S = 3.0  # how long to wait for senders' final statistics after the End
# How long after its tick an incomplete step record is written (a message was lost), by clock: a
# realtime run's log keeps up with its world; a lockstep step lacks a message only when it was lost or
# a loaded machine holds a live link back, for seconds.
FORCE_AFTER_S = {"realtime": 2.0, "lockstep": 10.0}
# Steps the monitor keeps open at once: a message claiming a step more than AHEAD_STEPS past the
# latest tick, or a new step once PENDING_LIMIT are open, is dropped and counted (forged far-future
# steps cannot grow the monitor's memory; a realtime team at 1000 steps/s keeps about 2000 open).
AHEAD_STEPS = 64
PENDING_LIMIT = 4096
VIEW_PERIOD_S = 0.25
DRAIN_PERIOD_S = 0.02  # the monitor is not on the critical path: it takes samples in batches
END_AFTER_INTERRUPT_S = 0.5  # a stopped monitor waits this long for the world's End


@dataclass
class PendingStep:
    """What the monitor has seen of one step so far: per robot, robot-to-robot messages and bytes sent
    and received; per category, every message stamped with the step."""

    tick: Tick | None = None
    commands: dict[int, Command] = field(default_factory=dict)
    measured: set[int] = field(default_factory=set)  # the robots whose measurement of the step was seen
    sent_messages: Counter[int] = field(default_factory=Counter)
    sent_bytes: Counter[int] = field(default_factory=Counter)
    received_messages: Counter[int] = field(default_factory=Counter)
    received_bytes: Counter[int] = field(default_factory=Counter)
    traffic_messages: Counter[str] = field(default_factory=Counter)
    traffic_bytes: Counter[str] = field(default_factory=Counter)
    notices: list[FaultNotice] = field(default_factory=list)
    links: Counter[tuple[str, int, int]] = field(default_factory=Counter)  # (kind, sender, receiver) -> messages

    def count_robot_message(self, kind: str, sender: int, receiver: int, size: int) -> None:
        """One robot-to-robot message of ``kind`` (request, reply, push) and ``size`` payload bytes,
        ``sender -> receiver`` (robot ids)."""
        self.links[kind, sender, receiver] += 1
        self.sent_messages[sender] += 1
        self.sent_bytes[sender] += size
        self.received_messages[receiver] += 1
        self.received_bytes[receiver] += size

    def complete(self) -> bool:
        """Tick and every live robot's command are in, the world's measurement of every robot that
        commanded (it travels on another link than the command it led to, and may arrive after it),
        and every robot-to-robot message its polls published: :func:`bus.faults.request_traffic` of
        each poll request, whose fate the fault notices tell (none: delivered once), and each push its
        command names (published once)."""
        if self.tick is None or not set(self.tick.live) <= set(self.commands) <= self.measured:
            return False
        polling = {robot for robot, command in self.commands.items() if command.trigger}
        fates: dict[tuple[int, int], Fate] = {}
        for notice in self.notices:
            if notice.subject == "request" and notice.sender in polling:
                fate = fates.get((notice.sender, notice.receiver), DELIVERED)
                if notice.what == "dropped":
                    fate = Fate(dropped=True)
                elif notice.what == "duplicated":
                    fate = replace(fate, copies=2)
                fates[notice.sender, notice.receiver] = fate
        expected = 2 * len(polling) * request_traffic(DELIVERED)
        expected += sum(request_traffic(fate) - request_traffic(DELIVERED) for fate in fates.values())
        expected += sum(len(getattr(command, "pushed", ())) for command in self.commands.values())
        return self.sent_messages.total() >= expected


# Categories whose every link the monitor must see exactly as its senders counted it. Monitoring
# traffic (statistics, fault notices) is not compared: a sender's final Stats cannot count itself.
COMPARED = ("robot", "world", "estimation")

STEPPED = (Tick, Measurement, Command, Request, Reply, Push, RangeReport, Estimate, FaultNotice)


class Recorder:
    """Turns deliveries into step records, in step order, each written once it is complete, or
    ``force_after_s`` seconds after its tick when later steps exist (a message was lost; see
    :data:`FORCE_AFTER_S`), or at the end;
    fault notices and robots joining or leaving become event records. Every record written is also
    handed to ``on_record``.

    Messages of different senders travel on different links, so a robot's command for step k may
    reach the monitor after the world's tick for k + 5: completeness, not arrival order, decides.
    """

    def __init__(self, writer: LogWriter, scenario: Scenario, on_record: Callable[[dict], None] | None = None,
                 force_after_s: float = FORCE_AFTER_S["realtime"]) -> None:
        self.writer = writer
        self.force_after_s = force_after_s
        self.scenario = scenario
        self.robots = scenario.robots
        self.on_record = on_record
        self.pending: dict[int, PendingStep] = {}
        self.next_step = 1
        self.latest_tick = 0
        self.tick_seen_at: dict[int, float] = {}
        self.late = 0
        self.dropped_ahead = 0  # messages for steps beyond the window of open steps
        self.digested_through = 0  # the last step whose digest entries were counted
        # Robots the world took out of its live set during the run (silent past the lockstep wait,
        # or left): cut off for the books, as robots whose alive token went.
        self.left_live: set[str] = set()
        self._live: set[int] | None = None

    def on_delivery(self, delivery: Delivery) -> None:
        message = delivery.message
        if not isinstance(message, STEPPED):
            return
        if message.step < self.next_step and not isinstance(message, FaultNotice):
            self.late += 1  # its step record is already written
            return
        if not self._opens(message.step):
            self.dropped_ahead += 1
            return
        entry = self._pending(message.step)
        entry.traffic_messages[message.category] += 1
        entry.traffic_bytes[message.category] += delivery.size
        if isinstance(message, Tick):
            self._tick(entry, message)
        elif isinstance(message, Command):
            entry.commands[message.robot] = message
        elif isinstance(message, Measurement):
            entry.measured.add(message.robot)
        elif isinstance(message, (Request, Reply, Push)):
            entry.count_robot_message(message.kind, message.sender, message.receiver, delivery.size)
        elif isinstance(message, FaultNotice):
            entry.notices.append(message)
            self.record({"type": "event", "event": message.what, "step": message.step,
                         "subject": message.subject, "sender": message.sender, "receiver": message.receiver,
                         "reason": message.reason or None, "delay_s": message.delay_s or None})

    def on_tick(self, tick: Tick) -> None:
        """The true state at the start of ``tick.step``, as a :class:`~bus.messages.Digest` carries it."""
        if tick.step >= self.next_step and self._opens(tick.step):
            self._tick(self._pending(tick.step), tick)

    def _tick(self, entry: PendingStep, tick: Tick) -> None:
        entry.tick = tick
        live = set(tick.live)
        if self._live is not None:
            self.left_live.update(robot_name(robot) for robot in self._live - live)
        self._live = live
        self.tick_seen_at[tick.step] = time.monotonic()
        self.latest_tick = max(self.latest_tick, tick.step)

    def count_reported(self, step: int, size: int, robots: tuple[str, int, int] | None = None,
                       measured: int | None = None) -> None:
        """Count a message of ``step`` (``size`` payload bytes) the monitor did not receive itself but
        a :class:`~bus.messages.Digest` reports: a world message (with ``measured``, the measurement
        of that robot), or with ``robots`` (kind, sender, receiver) a robot-to-robot message a
        command's ``robot_traffic`` names."""
        if step >= self.next_step and self._opens(step):
            entry = self._pending(step)
            if measured is not None:
                entry.measured.add(measured)
            category = "world" if robots is None else "robot"
            entry.traffic_messages[category] += 1
            entry.traffic_bytes[category] += size
            if robots is not None:
                entry.count_robot_message(*robots, size)

    def record(self, record: dict) -> None:
        """Write ``record`` to the log and hand it to ``on_record`` (the dashboard's model)."""
        self.writer.write(record)
        if self.on_record is not None:
            self.on_record(record)

    def _opens(self, step: int) -> bool:
        """Whether a message of ``step`` may be kept: its step is open already, or within
        ``AHEAD_STEPS`` of the latest tick (and of the next step to write) while fewer than
        ``PENDING_LIMIT`` steps are open."""
        if step in self.pending:
            return True
        return step <= max(self.latest_tick, self.next_step) + AHEAD_STEPS and len(self.pending) < PENDING_LIMIT

    def _pending(self, step: int) -> PendingStep:
        entry = self.pending.get(step)
        if entry is None:  # not setdefault: that would build a PendingStep for every message
            entry = self.pending[step] = PendingStep()
        return entry

    def flush(self, through: int | None = None) -> None:
        """Write complete steps in order and overdue ones as they are (also, once half of
        ``PENDING_LIMIT`` steps are open, the oldest: a step that waits long must not crowd later
        ones out); with ``through``, also every step up to that one (the last step the world
        completed) whatever is missing."""
        now = time.monotonic()
        while self.next_step in self.pending:
            entry = self.pending[self.next_step]
            overdue = self.latest_tick > self.next_step and (
                now - self.tick_seen_at[self.next_step] > self.force_after_s or len(self.pending) >= PENDING_LIMIT // 2)
            final = through is not None and self.next_step <= through
            if entry.tick is None or not (entry.complete() or overdue or final):
                return
            self._write(self.next_step, entry)
            del self.pending[self.next_step]
            del self.tick_seen_at[self.next_step]
            self.next_step += 1

    def _write(self, step: int, entry: PendingStep) -> None:
        tick = entry.tick
        assert tick is not None
        robots = range(self.robots)
        commands = entry.commands
        record = step_record(
            step=step,
            time=tick.time,
            positions=tick.positions,
            target=tick.target,
            live=list(tick.live),
            trigger=[commands[r].trigger if r in commands else None for r in robots],
            offset=[commands[r].guaranteed_offset if r in commands else None for r in robots],
            ages=[list(commands[r].ages) if r in commands else None for r in robots],
            centre=[list(commands[r].centre) if r in commands else None for r in robots],
            sent=([entry.sent_messages[r] for r in robots], [entry.sent_bytes[r] for r in robots]),
            received=([entry.received_messages[r] for r in robots], [entry.received_bytes[r] for r in robots]),
            traffic={category: [entry.traffic_messages[category], entry.traffic_bytes[category]]
                     for category in ("robot", "world", "estimation")},
            covariance=[_covariance(commands.get(r)) for r in robots],
            links=[[kind, sender, receiver, count] for (kind, sender, receiver), count in entry.links.items()],
            energy=[_energy(commands.get(r)) for r in robots],
        )
        self.record(record)


def _each(handlers: list[Callable[[dict], None]]) -> Callable[[dict], None] | None:
    """One callback calling every handler in turn (None: no handler; one: that handler itself)."""
    if len(handlers) <= 1:
        return handlers[0] if handlers else None

    def each(record: dict) -> None:
        for handler in handlers:
            handler(record)

    return each


def _covariance(command: Command | None) -> list[float] | None:
    """The covariance (``[xx, xy, yy]`` m^2) of the estimate a command's robot steered by, if any."""
    return None if command is None or command.covariance is None else list(command.covariance)


def _energy(command: Command | None) -> list[float] | None:
    """A robot's radio energy so far as its command reported it, [transmit, receive] joules."""
    return None if command is None or command.energy_j is None else list(command.energy_j)


def senders(scenario: Scenario) -> set[str]:
    """Everyone who sends in a run of ``scenario`` (the monitor only listens)."""
    return scenario.participants(monitor=False)


@dataclass
class MonitorReport:
    """What the monitor saw, and whether it matches what the senders counted."""

    received: list[Traffic]
    senders: dict[str, list[Traffic]]
    rejected: dict[str, int]
    rss_kib: dict[str, int]
    end: End | None
    late: int
    faults: Counter[str] = field(default_factory=Counter)  # robots' fault layers, summed (bus.faults.team_faults)
    notes: Counter[str] = field(default_factory=Counter)  # robots' protocol counters, summed
    rejected_by: dict[str, dict[str, int]] = field(default_factory=dict)  # payloads senders rejected
    energy_j: dict[str, list[float]] = field(default_factory=dict)  # robot -> radio energy [transmit, receive], J
    superseded: list[Traffic] = field(default_factory=list)  # messages of replaced lives, dropped at the door
    # participants whose alive token went, or that left the world's live set, during the run
    cut_off: set[str] = field(default_factory=set)
    silent: frozenset[str] = frozenset()  # senders one of whose lives left no books (killed)
    resumed: bool = False  # this monitor resumed the log of one that went away: it could not see everything

    def sender_rows(self) -> list[Traffic]:
        """Every traffic row of every sender's final statistics."""
        return [row for rows in self.senders.values() for row in rows]

    def sender_totals(self) -> dict[str, dict[str, int]]:
        return totals_by_category(self.sender_rows())

    def monitor_totals(self) -> dict[str, dict[str, int]]:
        return totals_by_category(self.received)

    def books(self) -> Books:
        """On every (kind, source, destination) link of the ``COMPARED`` categories, the messages the
        senders, every life of each, say they sent against those the monitor saw (taken in, or
        dropped at its door as a replaced life's: ``superseded``), shortfalls on links of a process
        cut off during the run being in flight (:func:`bus.counting.close_books`)."""
        return close_books(self.sender_rows(), [*self.received, *self.superseded], self.cut_off, COMPARED,
                           self.silent, unobserved=self.resumed)

    def consistent(self) -> bool:
        """Whether the books balance (:meth:`books`)."""
        return self.books().balanced

    def distrust(self) -> str | None:
        """Why this run's results cannot be trusted, or None (:func:`tools.runlog.derived.distrust`)."""
        return distrust({"consistent": self.consistent(), "notes": self.notes})


Refresh = Callable[[bool], None]  # redraw the display (must not wait for it); True once at the end


async def run_monitor(
    scenario: Scenario,
    seed: int,
    run: int,
    bus: BusConfig,
    log_path: Path,
    steps: int,
    clock: str,
    model: TeamModel | None = None,
    refresh: Refresh | None = None,
    exit_with_parent: bool = False,
    digests: bool = False,
    on_record: Callable[[dict], None] | None = None,
    resume: bool = False,
) -> tuple[int, MonitorReport | None]:
    """Monitor one run, feeding every step and event record to ``model`` and calling ``refresh`` a few
    times per second, and once more with True when the log is complete; returns the exit code and
    the report (None when stopped before the start). With ``digests`` the monitor receives no copy of
    the measurements, commands and robot-to-robot messages: it counts them from the world's digests
    (:func:`digested`). ``on_record`` is handed every step, event and end record too, as written
    (the live Foxglove view and ``--record``). With ``resume`` the monitor goes on with the log and
    books of a monitor of the same run that went away (:mod:`tools.monitor.checkpoint`)."""
    keys = Keys(run)
    report: MonitorReport | None = None
    if model is not None:
        model.expected = startup_names(scenario)

    def show_startup(roster: Roster) -> None:
        """Who is up so far, on the dashboard's start-up frame."""
        if model is not None and refresh is not None:
            model.up = roster.alive | {MONITOR}
            refresh(False)

    async def main(participant: Participant, roster: Roster, held: list) -> int:
        nonlocal report
        with LogWriter(log_path, resume=resume) as writer:
            handlers = [handler for handler in (None if model is None else model.add, on_record) if handler is not None]
            recorder = Recorder(writer, scenario, _each(handlers), FORCE_AFTER_S[clock])
            books = Tallies()
            if resume:
                books = resumed(participant, recorder, read_checkpoint(checkpoint_path(log_path), f"{run:08x}"))
            else:
                writer.header(scenario, "emulator", run, seed, clock, steps)
            participant.window = lambda message: far_ahead(message, max(recorder.latest_tick, recorder.next_step))
            code, report = await _watch(participant, recorder, roster, held, refresh, digests, books,
                                        checkpoint_path(log_path))
            # The step the world was in when it stopped never completed: it is not written.
            recorder.flush(through=report.end.step if report.end else None)
            end = {
                "type": "end",
                "steps": report.end.step if report.end else recorder.next_step - 1,
                "reason": report.end.reason if report.end else EndReason.MONITOR_STOPPED,
                "wall_s": report.end.wall_s if report.end else None,
                "traffic": [list(row) for row in report.received],
                "senders": {name: [list(row) for row in rows] for name, rows in report.senders.items()},
                "rejected": report.rejected,
                "late": recorder.late,
                "dropped_ahead": recorder.dropped_ahead,
                "rss_kib": report.rss_kib,
                "consistent": report.consistent(),
                "books": report.books().lines(),
                "faults": {name: report.faults[name] for name in (*FAULT_COUNTERS, "lost")},
                "notes": dict(report.notes),
                "rejected_by": report.rejected_by,
                "energy_j": report.energy_j,
                "superseded": [list(row) for row in report.superseded],
            }
            writer.write(end)
        with contextlib.suppress(OSError):
            checkpoint_path(log_path).unlink()  # the log is whole: nothing to resume
        if on_record is not None:
            on_record(end)
        if model is not None:
            model.add(end)
            model.status = (report.end.reason.text(report.end.step) if report.end
                            else "stopped" if code == STOPPED else "world lost")
        if refresh is not None:
            refresh(True)
        return code

    # A resumed monitor starts as soon as the world is there: robots killed meanwhile may not be.
    role = Role(name=MONITOR, needed={WORLD} if resume else senders(scenario), main=main,
                collect=monitored_keys(keys, digests), stats=lambda participant, code: None, on_gathering=show_startup)
    code = await perform(role, bus, keys, scenario.robots, Interrupts(exit_with_parent))
    return code, report


@dataclass
class Tallies:
    """What the monitor gathers besides the counts of its participant: every sender's final
    statistics (by life label), who was cut off during the run, how many lives of each robot the log
    has events for; ``recount_after``: a resumed monitor counts the world's replayed digest entries of
    the steps after this one (its predecessor counted those up to it), None: not resumed."""

    finals: dict[str, Stats] = field(default_factory=dict)
    cut_off: set[str] = field(default_factory=set)
    lives_recorded: dict[str, int] = field(default_factory=dict)
    recount_after: int | None = None
    replay_seen: bool = False  # a resumed monitor's: the world's replay has come (digests before it are in it)


def resumed(participant: Participant, recorder: Recorder, checkpoint: Checkpoint | None) -> Tallies:
    """Take up the log and books of the monitor that went away: go on after the last step its log
    holds, with its counts as of its last ``checkpoint`` (None: it left none; from nothing)."""
    recorder.next_step = recorder.writer.steps_written + 1
    recorder.latest_tick = recorder.writer.steps_written
    tallies = Tallies(recount_after=0)
    if checkpoint is not None:
        recorder.latest_tick = max(recorder.latest_tick, checkpoint.latest_tick)
        recorder.late, recorder.dropped_ahead = checkpoint.late, checkpoint.dropped_ahead
        recorder.digested_through = checkpoint.digested_through
        restore_counts(participant.counter, checkpoint.received, checkpoint.rejected)
        restore_counts(participant.fenced, checkpoint.fenced)
        participant.lives.update(checkpoint.lives)
        participant.life_history.update({name: list(lives) for name, lives in checkpoint.life_history.items()})
        tallies = Tallies(dict(checkpoint.finals), set(checkpoint.cut_off), dict(checkpoint.lives_recorded),
                          checkpoint.digested_through)
    recorder.record({"type": "event", "event": "monitor", "subject": "resumed", "step": recorder.next_step - 1,
                     "wall": time.time()})
    return tallies


def take_checkpoint(participant: Participant, recorder: Recorder, tallies: Tallies) -> Checkpoint:
    """The monitor's tallies now (:mod:`tools.monitor.checkpoint`)."""
    return Checkpoint(
        run=f"{participant.keys.run:08x}", digested_through=recorder.digested_through,
        latest_tick=recorder.latest_tick, late=recorder.late, dropped_ahead=recorder.dropped_ahead,
        received=participant.counter.received_table(), rejected=dict(participant.counter.rejected),
        fenced=participant.fenced.received_table(), finals=tallies.finals,
        cut_off=sorted(tallies.cut_off | recorder.left_live),
        lives=participant.lives, life_history=participant.life_history, lives_recorded=tallies.lives_recorded)


async def _watch(
    participant: Participant,
    recorder: Recorder,
    roster: Roster,
    events: list,
    refresh: Refresh | None,
    digests: bool = False,
    tallies: Tallies | None = None,
    checkpoint_at: Path | None = None,
) -> tuple[int, MonitorReport]:
    """Record until the run has ended and everything every sender says it sent has been seen (or
    nothing has arrived for ``FINAL_STATS_GRACE_S``: a sender died); with ``digests``, the world's
    digests count for the messages the monitor does not receive (:data:`DIGESTED`). Every
    ``CHECKPOINT_PERIOD_S`` the tallies go to ``checkpoint_at`` (if given)."""
    tallies = tallies or Tallies()
    finals, cut_off, lives_recorded = tallies.finals, tallies.cut_off, tallies.lives_recorded
    end: End | None = None
    code = 0
    interrupted_at = 0.0
    last_view = last_checkpoint = 0.0
    loop = asyncio.get_running_loop()
    last_event_at = loop.time()
    team = senders(recorder.scenario)
    while True:
        for event in events:
            if isinstance(event, Delivery) and isinstance(event.message, Digest):
                if event.message.replayed:  # the steps the world kept while the monitor was away
                    if tallies.recount_after is not None:
                        tallies.replay_seen = True
                        replayed(participant, recorder, event.message, digests, tallies.recount_after)
                elif digests and (tallies.recount_after is None or tallies.replay_seen):
                    # (else a world digesting for an auditing monitor: what it says is seen already; or a
                    # digest the world sent as this resumed monitor came up, which its replay holds too)
                    digested(participant, recorder, event.message)
            elif isinstance(event, Delivery):
                message = event.message
                recorder.on_delivery(event)
                if isinstance(message, Stats) and message.final:
                    finals[life_label(message.name, event.life)] = message
                elif isinstance(message, End):
                    end = message
            elif isinstance(event, Presence):
                roster.update(event)
                if event.kind == "alive" and not event.up and end is None:
                    cut_off.add(event.name)
                if event.kind == "alive" and robot_index(event.name) is not None:
                    recorder.record({"type": "event", "event": "joined" if event.up else "left",
                                     "robot": event.name, "step": recorder.latest_tick, "wall": time.time()})
            elif isinstance(event, Interrupt) and not code:
                code, interrupted_at = STOPPED, loop.time()
        if events:
            last_event_at = loop.time()
        recorder.flush()
        if code and (end is not None or loop.time() - interrupted_at > END_AFTER_INTERRUPT_S):
            break  # stopped: keep what the world's End says completed, if it comes in time
        if end is not None:
            # every sender's newest life has sent its books (an older life's do not stand for them)
            accounted = all(life_label(name, participant.lives.get(name, 0)) in finals or roster.gone_for_good(name)
                            for name in team)
            if (accounted and _seen_everything(participant, finals)) or (
                loop.time() - last_event_at > FINAL_STATS_GRACE_S
            ):
                break
        elif roster.gone_for_good(WORLD):
            code = 1  # the world went away without ending the run
            break
        now = time.monotonic()
        if refresh is not None and now - last_view >= VIEW_PERIOD_S:
            refresh(False)
            last_view = now
        if checkpoint_at is not None and now - last_checkpoint >= CHECKPOINT_PERIOD_S:
            write_checkpoint(checkpoint_at, take_checkpoint(participant, recorder, tallies))
            last_checkpoint = now
        await asyncio.sleep(DRAIN_PERIOD_S)
        events = participant.drain()
        record_new_lives(participant, recorder, lives_recorded)
    report = MonitorReport(
        received=participant.counter.received_table(),
        senders={name: stats.sent for name, stats in finals.items()},
        rejected=participant.counter.rejected_table(),
        rss_kib={name: stats.rss_kib for name, stats in finals.items()} | {MONITOR: peak_rss_kib()},
        end=end,
        late=recorder.late,
        faults=Counter(team_faults([stats.faults for stats in finals.values()])),
        notes=sum((Counter(stats.notes) for stats in finals.values()), Counter()),
        rejected_by={name: stats.rejected for name, stats in finals.items() if stats.rejected},
        energy_j={name: list(stats.energy_j) for name, stats in finals.items() if stats.energy_j is not None},
        superseded=participant.fenced.received_table(),
        cut_off=cut_off | recorder.left_live | {stats.name for name, stats in finals.items() if name != stats.name},
        silent=frozenset(name for name, lives in participant.life_history.items()
                         if any(life_label(name, life) not in finals for life in lives)),
        resumed=tallies.recount_after is not None,
    )
    return code, report


# The kinds a world's Digest accounts for: measurements and commands by the world's own counts, and
# robot-to-robot messages by the robots' own (each command's ``robot_traffic``).
DIGESTED = ("measurement", "command", "request", "reply", "push")


def monitored_keys(keys: Keys, digests: bool) -> tuple[str, ...]:
    """The key expressions the monitor subscribes to: the whole run when it audits, else every kind
    the world's digests do not account for (:data:`DIGESTED`)."""
    if not digests:
        return (keys.everything,)
    return tuple(keys.data("*", "*", kind) for kind in KINDS if kind not in DIGESTED)


def digested(participant: Participant, recorder: Recorder, digest: Digest) -> None:
    """Record each step's tick ``digest`` carries, and count the messages it reports as if the monitor
    had received them: the measurements and commands by the world's own counts (what it published,
    what it received), the robot-to-robot messages by each commanding robot's own
    (:attr:`bus.messages.Command.robot_traffic`)."""
    for entry in digest.entries:
        if entry.tick is not None:
            recorder.on_tick(entry.tick)
        _digested_entry(participant, recorder, entry, count=True, record=True)


def replayed(participant: Participant, recorder: Recorder, digest: Digest, digests: bool, recount_after: int) -> None:
    """Take the steps a world replays to a resumed monitor (:mod:`world.backlog`): record those the
    log lacks and, with ``digests``, count the messages of those after ``recount_after`` (the
    predecessor's checkpoint counted the others); an auditing monitor counts only what it saw."""
    for entry in digest.entries:
        record, count = entry.step >= recorder.next_step, digests and entry.step > recount_after
        if record and entry.tick is not None:
            recorder.on_tick(entry.tick)
        if record or count:
            _digested_entry(participant, recorder, entry, count, record)
    if digest.entries:  # the world completed these steps: what they lack now, they lack for good
        recorder.flush(through=digest.entries[-1].step)


def _digested_entry(participant: Participant, recorder: Recorder, entry: DigestEntry, count: bool,
                    record: bool) -> None:
    """Count (``count``) and give the recorder (``record``) the messages ``entry`` reports."""
    counter = participant.counter
    if count:
        recorder.digested_through = max(recorder.digested_through, entry.step)
    for robot, size in entry.measurements:
        if count:
            counter.count_received(("measurement", WORLD, robot_name(robot)), size)
        if record:
            recorder.count_reported(entry.step, size, measured=robot)
    for command, size in entry.commands:
        source = robot_name(command.robot)
        if count:
            counter.count_received(("command", source, WORLD), size)
        if record:
            recorder.on_delivery(Delivery(command, Route(WORLD, source, "command"), size))
        for kind, peer, copies, each in command.robot_traffic:
            sender, receiver = (peer, command.robot) if ROBOT_TRAFFIC_KINDS[kind] == "reply" else (command.robot, peer)
            link = (ROBOT_TRAFFIC_KINDS[kind], robot_name(sender), robot_name(receiver))
            for _ in range(copies):
                if count:
                    counter.count_received(link, each)
                if record:
                    recorder.count_reported(command.step, each, (ROBOT_TRAFFIC_KINDS[kind], sender, receiver))


def record_new_lives(participant: Participant, recorder: Recorder, recorded: dict[str, int]) -> None:
    """Write a ``life`` event to the log for every new life of a robot the monitor has heard from
    since the last call (a restarted process; the first life of each robot goes unsaid)."""
    for name, lives in participant.life_history.items():
        for life in lives[recorded.get(name, 0):]:
            if life > 1:
                recorder.record({"type": "event", "event": "life", "robot": name, "subject": f"life {life}",
                                 "step": recorder.latest_tick, "wall": time.time()})
        recorded[name] = len(lives)


def _seen_everything(participant: Participant, finals: dict[str, Stats]) -> bool:
    """Whether the monitor has seen (taken in, or dropped as a replaced life's) every message each
    finished sender, every life of it, says it sent."""
    said: Counter[str] = Counter()
    for stats in finals.values():
        said[stats.name] += sum(row[3] for row in stats.sent)
    seen: Counter[str] = Counter()
    for counts in (participant.counter.received_messages, participant.fenced.received_messages):
        for (_kind, source, _destination), count in counts.items():
            seen[source] += count
    return all(seen[name] >= count for name, count in said.items())
