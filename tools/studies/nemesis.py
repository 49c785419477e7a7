"""``ringtrack experiment nemesis``: many seeded random fault schedules against live teams, and a
checker that says, for each, what broke.

Every schedule is one ``spawn`` run with the wire audit on (the monitor observes every message
itself) and a random nemesis plan (:func:`tools.team.nemesis.random_plan`): robots killed and
restarted as their next life, paused below and past the liveliness lease, and split brains (a robot
frozen past the lease, a new life of it started, the old one woken); every fifth schedule ends by
killing the monitor or the world, or kills the monitor and restarts it (the world holds the run and
the new monitor resumes the log). The checker reads the run folder: whether the ring
re-formed and at which step, the tracking quality after it (mean true Cerr in degrees, and Terr in
metres for a moving target, from the step it re-formed on), overlapping lives (two processes acting
as the same life of a robot: must be 0), whether the books balance (they must), and whether a lost
monitor or world was noticed (every process ended on its own, and the world said why), and whether
a restarted monitor resumed the log (every step written once, in order, and the run ended whole).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

from ringtrack.bus.lives import SUPERSEDED_MARK
from ringtrack.bus.runtime import STOPPED
from ringtrack.tools.runlog.derived import step_errors
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.nemesis import Fault, random_plan
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import Scenario, apply_overrides, resolve

Clock = Literal["lockstep", "realtime"]
LEASE_S = 2.0  # the teams' liveliness lease: pauses of 2.5-4 s outlast it
RATE = 5.0  # realtime teams run five times faster than the wall clock
# At least a six-robot lockstep team's pace on an idle 2-core machine: a lockstep run lasts at least
# as long as a realtime one, so that every fault of the plan falls within it.
LOCKSTEP_STEPS_PER_S = 500.0
FATAL_EVERY = 5  # every fifth schedule ends by killing the monitor or the world, or restarts the monitor
MONITOR_AWAY_S = 1.5  # s: how long a restarted monitor's schedule leaves the run without one


class ScheduleRow(msgspec.Struct, frozen=True):
    """What one schedule came to (see the module's text); ``noticed`` is None when no monitor or world
    was killed for good (none in the plan, or the run was over before the kill fell due),
    ``reformed_at_step`` (the first step from which the whole team was in the ring to the end) None
    when one was (the run ended early) or the ring never re-formed."""

    schedule: int
    seed: int
    clock: Clock
    plan: str
    exit_code: int
    steps: int
    reformed: bool
    reformed_at_step: int | None
    cerr_after_deg: float | None
    terr_after_m: float | None
    overlapping_lives: int
    fenced_lives: int
    books_balanced: bool
    books: list[str]
    noticed: bool | None
    resumed: bool | None = None  # None: the plan restarted no monitor
    fenced_after_s: list[float] = []  # per fenced life: wall seconds from its waking to its line saying it stops


def lockstep_steps(scenario: Scenario) -> int:
    """The steps of a lockstep schedule: as many as make it last at least as long (wall seconds) as a
    realtime schedule of ``scenario.max_steps`` steps, so that the same faults fit into both."""
    return round(scenario.max_steps * scenario.control.dt / RATE * LOCKSTEP_STEPS_PER_S)


def plan_for(schedule: int, seed: int, scenario: Scenario) -> list[Fault]:
    """The faults of schedule ``schedule``: a random plan, every fault over within the first two thirds
    of a realtime run of ``scenario.max_steps`` steps (wall seconds), and for every
    :data:`FATAL_EVERY`-th, in turn, a monitor kill, a world kill or a monitor kill and restart
    (``MONITOR_AWAY_S`` later) at three quarters of it."""
    duration_s = scenario.max_steps * scenario.control.dt / RATE
    faults = random_plan(seed, scenario.robots, max(1.0, 2.0 * duration_s / 3.0), lease_s=LEASE_S)
    if schedule % FATAL_EVERY == FATAL_EVERY - 1:
        turn, at_s = (schedule // FATAL_EVERY) % 3, round(0.75 * duration_s, 1)
        faults.append(Fault("kill", "world" if turn == 1 else "monitor", at_s))
        if turn == 2:
            faults.append(Fault("restart", "monitor", round(at_s + MONITOR_AWAY_S, 1)))
    return faults


def run_schedule(schedule: int, seed: int, clock: Clock, scenario: Scenario, runs: Path, settle: int,
                 fixed: list[Fault] | None = None) -> ScheduleRow:
    """Run one schedule as a spawned team and check it: ``scenario.max_steps`` steps in realtime, as
    many as last as long in lockstep (:func:`lockstep_steps`); its faults are ``fixed`` (every
    schedule the same plan) or drawn (:func:`plan_for`)."""
    faults = plan_for(schedule, seed, scenario) if fixed is None else fixed
    if clock == "lockstep":
        scenario = resolve(apply_overrides(scenario.spec, max_steps=lockstep_steps(scenario)), scenario.name)
    plan = TeamPlan(scenario=scenario, clock=clock, rate=RATE, runs=runs, dashboard=False, quiet=True,
                    lease=LEASE_S, audit=True, nemesis=faults)
    result = spawn_team(plan)
    if result.exit_code == STOPPED:  # Ctrl-C or SIGTERM: spawn ended the team; the study ends too
        raise KeyboardInterrupt
    folder = Path(result.folder)
    restarted = any(fault.action == "restart" and fault.target == "monitor" for fault in faults)
    # a kill carried out (a run may be over before a late one falls due: it then tests nothing)
    killed = {entry["fault"].removeprefix("kill ").split("@")[0] for entry in result.nemesis
              if entry["fault"].startswith("kill ")}
    fatal = None if restarted else next((fault.target for fault in faults if fault.target in ("monitor", "world")
                                         and fault.target in killed), None)
    log = read_log(folder / "log.jsonl") if (folder / "log.jsonl").is_file() else None
    records = [] if log is None else log.steps
    whole = [record for record in records if len(record["live"]) == scenario.robots]
    broken = [record["step"] for record in records if len(record["live"]) < scenario.robots]
    reformed_at = (broken[-1] + 1 if broken else 1) \
        if fatal is None and records and len(records[-1]["live"]) == scenario.robots else None
    after = [record for record in whole if reformed_at is not None and record["step"] >= max(reformed_at, settle)]
    errors = np.array([step_errors(record) for record in after]) if after else np.empty((0, 2))
    terr = float(np.nanmean(errors[:, 1])) if len(errors) and not np.isnan(errors[:, 1]).all() else None
    return ScheduleRow(
        schedule=schedule, seed=seed, clock=clock, plan=", ".join(str(fault) for fault in faults),
        exit_code=result.exit_code, steps=len(records), reformed=reformed_at is not None,
        reformed_at_step=reformed_at,
        cerr_after_deg=float(np.mean(errors[:, 0])) if len(errors) else None,
        terr_after_m=terr if scenario.moving else None,
        overlapping_lives=result.id_collisions, fenced_lives=result.fenced_lives,
        books_balanced=fatal is not None or result.distrust is None,
        books=[] if log is None or log.end is None else log.end.get("books", []),
        noticed=None if fatal is None else noticed(folder, fatal, result.stopped),
        resumed=None if not restarted else log is not None and resumed_whole(log.steps, log.events, log.end),
        fenced_after_s=fenced_after_s(folder, result.nemesis),
    )


def fenced_after_s(folder: Path, struck: list[dict]) -> list[float]:
    """For every robot process of the run folder that stopped as a replaced life, the wall seconds
    from the nemesis waking it (its ``wake`` in ``struck``) to the line that says it stops (the last
    its standard error holds: the file's modification time)."""
    woken = {entry["fault"].removeprefix("wake "): entry["wall"] for entry in struck
             if entry["fault"].startswith("wake ")}
    stops = []
    for path in sorted(folder.glob("r*.stderr")):
        name = path.stem.split("@")[0]
        if name in woken and SUPERSEDED_MARK in path.read_text(errors="replace"):
            stops.append(round(path.stat().st_mtime - woken[name], 2))
    return stops


def resumed_whole(steps: list[dict], events: list[dict], end: dict | None) -> bool:
    """Whether a restarted monitor resumed the log: it says so, every step is written once and in
    order, and the log ends with the end record of a run that was not cut short."""
    return any(event["event"] == "monitor" and event.get("subject") == "resumed" for event in events) and \
        [record["step"] for record in steps] == list(range(1, len(steps) + 1)) and end is not None \
        and end["steps"] == len(steps)


def noticed(folder: Path, victim: str, stopped: str | None) -> bool:
    """Whether the team noticed its lost ``victim`` on its own: spawn did not have to stop it (a
    stall), and the world said the monitor went away (or the robots that the world did)."""
    if stopped is not None:
        return False
    if victim == "monitor":
        return "the monitor went away" in (folder / "world.stderr").read_text(errors="replace")
    robots = list(folder.glob("r*.stderr"))
    return any("the world went away" in path.read_text(errors="replace") for path in robots)


class NemesisStudy(msgspec.Struct, frozen=True):
    """A nemesis study: its settings, one row per schedule and the totals the issue of trust asks for."""

    scenario: str
    schedules: int
    seed: int
    steps: int
    rows: list[ScheduleRow]
    overlapping_lives: int
    unbalanced_books: int
    lost_noticed: str  # "k/n": lost monitors or worlds noticed of those killed
    monitors_resumed: str  # "k/n": restarted monitors that resumed the log whole
    fenced_within_s: float | None  # the longest a replaced life took from its waking to stop (None: none fenced)
    reformed: str  # "k/n" of the schedules that killed neither


def nemesis_study(scenario: Scenario, schedules: int, seed: int, clocks: tuple[Clock, ...], settle: int,
                  on_row: Callable[[ScheduleRow], None] | None = None, runs: Path | None = None,
                  fixed: list[Fault] | None = None) -> NemesisStudy:
    """Run ``schedules`` schedules of ``scenario.max_steps`` steps, alternating ``clocks``, schedule i
    seeded ``seed + i`` (or every one with the ``fixed`` plan); ``runs`` keeps the run folders (None:
    a scratch folder)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="ringtrack-nemesis-") as scratch:
        for schedule in range(schedules):
            clock = clocks[schedule % len(clocks)]
            row = run_schedule(schedule, seed + schedule, clock, scenario, runs or Path(scratch), settle, fixed)
            rows.append(row)
            if on_row is not None:
                on_row(row)
    fatal = [row for row in rows if row.noticed is not None]
    survivable = [row for row in rows if row.noticed is None]
    return NemesisStudy(
        scenario=scenario.name, schedules=schedules, seed=seed, steps=scenario.max_steps, rows=rows,
        overlapping_lives=sum(row.overlapping_lives for row in rows),
        unbalanced_books=sum(not row.books_balanced for row in rows),
        lost_noticed=f"{sum(bool(row.noticed) for row in fatal)}/{len(fatal)}",
        monitors_resumed=f"{sum(bool(row.resumed) for row in rows if row.resumed is not None)}/"
                         f"{sum(row.resumed is not None for row in rows)}",
        reformed=f"{sum(row.reformed for row in survivable)}/{len(survivable)}",
        fenced_within_s=max((stop for row in rows for stop in row.fenced_after_s), default=None),
    )


def study_json(study: NemesisStudy) -> str:
    return json.dumps(msgspec.to_builtins(study), indent=1)
