"""What a team of processes is asked to do (:class:`TeamPlan`) and what it came to (:class:`TeamResult`).

``ringtrack spawn`` builds a plan from its flags, :func:`tools.team.spawn.spawn_team` runs it, and the
result is the run folder's ``summary.json`` (``spawn --json``). Times in seconds, memory in KiB,
energy in joules.
"""

from __future__ import annotations

import enum
from pathlib import Path
from typing import Literal

import msgspec

from ringtrack.agents.summary import SETTLE_STEPS, RunSummary
from ringtrack.bus.config import LEASE_S
from ringtrack.bus.counting import Totals
from ringtrack.bus.messages import EndReason
from ringtrack.bus.radio import EnergyReport
from ringtrack.tools.team.nemesis import Fault
from ringtrack.world.scenario import Scenario

LOCKSTEP_WAIT_S = LEASE_S  # a frozen robot is seen gone (liveliness) after about as long

Clock = Literal["lockstep", "realtime"]


class TeamPlan(msgspec.Struct, kw_only=True, frozen=True):
    """A team to run: the scenario and how its processes run it.

    With ``until_converged`` the world ends the run at convergence (at most ``scenario.max_steps``),
    else it runs exactly ``scenario.max_steps`` steps. ``clock`` "lockstep" waits for every robot
    each step (equal to the engine), "realtime" makes a step every ``dt / rate`` wall seconds. The
    monitor draws its dashboard when ``dashboard`` is True, summary lines when False, and decides by
    its terminal when None; ``quiet`` sends its display to ``RUN_FOLDER/monitor.stdout``.
    ``topology`` "mesh" links every pair of processes directly (Zenoh peers), "star" makes the world
    a Zenoh router every other process reaches as a client (None: mesh up to 16 participants).
    ``robots_per_process`` packs that many robots into one process, each still its own participant.
    ``secure`` (a team folder of ``ringtrack certs``) makes every link mutual TLS with access
    control; ``all_robots`` lists every robot in the monitor's report. In lockstep the world treats
    a robot silent ``lockstep_wait`` seconds in one step as gone, and a poll gives up on a reply
    after half of that; every process announces a liveliness ``lease`` of that many seconds. With
    ``audit`` the monitor receives a copy of every message (else, in lockstep, the world's digests
    account for measurements and commands). A moving target's summary means leave out the first
    ``settle`` steps. ``start`` "fork" forks the robot processes from one launcher that has imported
    their code, "exec" starts each as a fresh interpreter (None: fork where it works, Linux).
    ``foxglove`` ``(host, port)`` has the monitor serve the run live to Foxglove, ``record`` has it
    record the run as MCAP (:mod:`tools.viz.sink`); both off by default. ``nemesis`` schedules
    process faults against the team (:mod:`tools.team.nemesis`)."""

    scenario: Scenario
    clock: Clock = "lockstep"
    rate: float = 1.0
    runs: Path = Path("runs")
    log_path: Path | None = None
    dashboard: bool | None = None
    until_converged: bool = False
    quiet: bool = False
    topology: Literal["mesh", "star"] | None = None
    robots_per_process: int = 1
    secure: Path | None = None
    all_robots: bool = False
    lockstep_wait: float = LOCKSTEP_WAIT_S
    lease: float = LEASE_S
    audit: bool = False
    settle: int = SETTLE_STEPS
    start: Literal["fork", "exec"] | None = None
    foxglove: tuple[str, int] | None = None
    record: Path | None = None
    nemesis: list[Fault] = msgspec.field(default_factory=list)


class Stop(enum.Enum):
    """Why spawn stopped a team before its world ended the run."""

    INTERRUPTED = "interrupted by the user (Ctrl-C)"
    TERMINATED = "terminated (SIGTERM)"
    STALLED = "stalled"

    @property
    def by_signal(self) -> bool:
        """Stopped by a signal to spawn (exit code 130), not by a hung team (exit code 1)."""
        return self is not Stop.STALLED


class TeamResult(msgspec.Struct, kw_only=True):
    """What a team's run came to: its outcome (the summary ``simulate`` gives, from the run log;
    None when the log holds no step), the traffic by category and kind as the monitor counted it
    (by the senders' counts when the monitor was lost), and how the processes fared."""

    run: str  # the run id, 8 hex digits
    clock: Clock
    folder: str
    log: str
    pids: dict[str, int]
    wall_s: float
    topology: str = "mesh"
    outcome: RunSummary | None = None
    messages: dict[str, int] = msgspec.field(default_factory=dict)  # category -> messages
    bytes: dict[str, int] = msgspec.field(default_factory=dict)  # category -> payload bytes
    by_kind: dict[str, Totals] = msgspec.field(default_factory=dict)
    monitor_equals_senders: bool | None = None
    monitor_lost: bool = False
    uncounted: list[str] = msgspec.field(default_factory=list)  # monitor lost: senders that left no counts
    faults: dict[str, int] = msgspec.field(default_factory=dict)
    rejected: dict[str, int] = msgspec.field(default_factory=dict)
    rss_kib: dict[str, int] = msgspec.field(default_factory=dict)
    end_reason: EndReason | None = None
    id_collisions: int = 0
    nemesis: list[dict] = msgspec.field(default_factory=list)  # the faults carried out (tools.team.nemesis)
    fenced_lives: int = 0  # robot processes stopped because a newer life of their id replaced them
    distrust: str | None = None  # why the results cannot be trusted (tools.runlog.derived.distrust)
    energy: EnergyReport | None = None  # None unless every robot reported its energy
    steps_per_s: float | None = None
    startup_s: float | None = None  # from the first start to the first step in the log
    failures: dict[str, int | None] = msgspec.field(default_factory=dict)  # process -> exit code, of those that crashed
    stopped: str | None = None  # why spawn stopped the team early (a :class:`Stop`, and what it waited for)
    exit_code: int = 0
