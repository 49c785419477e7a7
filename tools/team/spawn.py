"""``ringtrack spawn``: start a world, N robots and a monitor as separate OS processes over Zenoh.

Everything of a run goes into one run folder (``runs/<UTC time>-<name>-<run id>/`` by default): the
resolved scenario, ``run.json`` (run id, endpoints: what ``ringtrack robot --join`` needs to restart
a crashed robot), the run log, each process's standard error and the summary JSON. The world
listens on a free loopback port and announces it; the others connect to it and gossip links the
rest. Completion, Ctrl-C and SIGTERM all end every process within 2 s.

On a terminal, spawn draws the dashboard's start-up frame itself before it starts any process, and
hands the terminal to the monitor once the monitor is ready to draw (:mod:`tools.dashboard.startup`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import math
import signal
import time
from dataclasses import dataclass
from pathlib import Path

from ringtrack.agents.process import FENCED
from ringtrack.agents.summary import summarise
from ringtrack.bus.config import LOOPBACK_ANY_PORT
from ringtrack.bus.counting import totals_by_category, totals_by_kind
from ringtrack.bus.keys import MONITOR, new_run_id, robot_index, robot_name
from ringtrack.bus.lives import SUPERSEDED_MARK
from ringtrack.bus.messages import EndReason
from ringtrack.bus.radio import EnergyReport, energy_report
from ringtrack.bus.security import SECURE_LOOPBACK_ANY_PORT, check_team
from ringtrack.tools.dashboard.startup import StartupView
from ringtrack.tools.output.console import UsageError, err, out, warn_if_threshold_loose
from ringtrack.tools.output.files import OutputError, write_json
from ringtrack.tools.runlog.derived import distrust
from ringtrack.tools.runlog.log import LogWriteError, append_records, history_from_log, last_logged_step, read_log
from ringtrack.tools.team.nemesis import Nemesis, monitor_grace_s
from ringtrack.tools.team.plan import Clock, Stop, TeamPlan, TeamResult
from ringtrack.tools.team.supervisor import (
    FORK_WORKS,
    ROLE_COMMAND,
    Child,
    Supervisor,
    Terminated,
    terminate_as_exception,
)
from ringtrack.world.scenario import Scenario

STALL_TIMEOUT_S = 60.0
STARTUP_S_PER_PROCESS = 2.0  # start-up allowance per process on top of STALL_TIMEOUT_S (startup_limit)
CRITICAL = frozenset({"world", "monitor", "fusion"})  # processes whose failure ends the run
MESH_LIMIT = 16  # Zenoh participants: more use the star topology (a full mesh of n needs n(n-1)/2 links)
PROCESS_MIB = 80  # resident memory of one robot process (measured 55-75 MiB), for the process budget
MAX_PROCESSES = 1024


def run_folder(runs: Path, scenario: Scenario, run: int) -> Path:
    """Make ``runs/<UTC time>-<name>-<run id>/``; a ``runs`` that cannot hold it (a file, a read-only
    file system, no permission) is a :class:`UsageError` naming ``--runs``, before any process starts."""
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    folder = runs / f"{stamp}-{scenario.name}-{run:08x}"
    try:
        folder.mkdir(parents=True, exist_ok=False)
    except OSError as error:
        problem = "it is not a folder" if isinstance(error, NotADirectoryError) else error.strerror
        raise UsageError(f"--runs {runs}: cannot make a run folder there ({problem}); give a writable folder "
                         "with --runs DIR") from None
    return folder


def spawn_team(plan: TeamPlan) -> TeamResult:
    """Run the team ``plan`` describes and return what it came to (also written to
    ``RUN_FOLDER/summary.json``). Completion, Ctrl-C, SIGTERM and a stall all end every process."""
    scenario = plan.scenario
    processes = robot_processes(plan)
    if plan.start == "fork" and not FORK_WORKS:
        raise UsageError("--start fork: forking robot processes needs Linux (os.fork and pidfd); use --start exec")
    start = plan.start or ("fork" if FORK_WORKS else "exec")
    listen = LOOPBACK_ANY_PORT if plan.secure is None else secured(plan.secure, scenario)
    warn_if_threshold_loose(scenario)
    run = new_run_id()
    folder = run_folder(plan.runs, scenario, run)
    # The start-up frame before anything else: on a terminal only (a pipe nobody reads must not hold
    # spawn up), and only where the monitor draws its dashboard.
    handover = folder / "display.handover"
    view = startup_view(scenario, plan.clock, handover) \
        if not plan.quiet and plan.dashboard is not False and out.is_terminal else None
    (folder / "scenario.toml").write_bytes(scenario.to_toml())
    log_path = plan.log_path or folder / "log.jsonl"
    topology = plan.topology or ("mesh" if len(scenario.participants()) <= MESH_LIMIT else "star")
    started = time.perf_counter()
    first_step = FirstStep(log_path, started)
    if not plan.quiet:
        fusion = ", the fusion centre" if scenario.centralized else ""
        err.print(f"spawn: run {run:08x} in {folder}: starting the world, the monitor{fusion} and {scenario.robots} "
                  f"robots in {processes} processes", highlight=False)
    stop: Stop | None = None
    nemesis: Nemesis | None = None
    critical = set(CRITICAL)
    stalled = ""
    stop_signal = signal.SIGTERM
    with Supervisor(folder) as supervisor:
        supervisor.leader = "world"
        try:
            with terminate_as_exception(), view or contextlib.nullcontext():
                robots = start_team(supervisor, plan, TeamLaunch(run, folder, log_path, topology, listen, start, view,
                                                                 started))
                nemesis = unleash(plan, supervisor, folder, log_path, robots, start, critical)
                # A robot may crash and be restarted (ringtrack robot --join); the run goes on.
                def poll() -> None:
                    first_step()
                    if nemesis is not None:
                        nemesis.tick(first_step.since(), over=not world_running(supervisor))

                # A nemesis that kills the world or the monitor wants to see the others notice on
                # their own: from then on no failure ends the wait early (the stall guard remains).
                supervisor.wait(critical=critical, stall_s=STALL_TIMEOUT_S, watched=log_path, on_poll=poll,
                                started=lambda: first_step.after is not None,
                                startup_s=startup_limit(len(supervisor.children)))
        except KeyboardInterrupt:
            stop, stop_signal = Stop.INTERRUPTED, signal.SIGINT  # the children say so too
        except Terminated:
            stop = Stop.TERMINATED
        except TimeoutError as error:
            stop, stalled = Stop.STALLED, f"{error} {stalled_at(log_path, folder)}"
        finally:
            if nemesis is not None:
                nemesis.wake_all()
            supervisor.stop(stop_signal=stop_signal)
    if stop is None:
        for line in _failure_lines(supervisor, log_path):
            err.print(line, highlight=False, markup=False)
    if nemesis is not None and nemesis.struck:
        append_records(log_path, nemesis.events())
    result = _result(scenario, folder, log_path, plan.clock, run, supervisor, time.perf_counter() - started,
                     plan.settle)
    result.topology = topology
    result.startup_s = first_step.after
    result.nemesis = [dataclasses.asdict(struck) for struck in nemesis.struck] if nemesis is not None else []
    result.fenced_lives = len(fenced(supervisor))
    result.failures = failures(supervisor)
    result.stopped = None if stop is None else f"{stop.value}: {stalled}" if stalled else stop.value
    result.exit_code = 130 if stop is not None and stop.by_signal else \
        int(bool(result.failures or stop or result.distrust))
    return reported(result, folder, log_path)


def robot_processes(plan: TeamPlan) -> int:
    """How many robot processes the plan needs; a :class:`UsageError` when this machine cannot hold
    them (:func:`process_budget`) or ``robots_per_process`` is below 1."""
    robots, per_process = plan.scenario.robots, plan.robots_per_process
    if per_process < 1:
        raise UsageError(f"--robots-per-process {per_process}: give at least 1")
    processes, budget = math.ceil(robots / per_process), process_budget()
    if processes > budget:
        raise UsageError(
            f"--robots {robots}: {processes} robot processes of about {PROCESS_MIB} MiB each are more than "
            f"this machine holds ({budget}); host several per process with --robots-per-process "
            f"{math.ceil(robots / budget)}"
        )
    return processes


@dataclass(frozen=True)
class TeamLaunch:
    """Where and how one run's processes start: its id, run folder and log, the topology of its
    Zenoh sessions, the endpoint the world listens on, "fork" or "exec", the start-up frame, and
    when spawn started (``time.perf_counter``, seconds)."""

    run: int
    folder: Path
    log_path: Path
    topology: str
    listen: str
    start: str
    view: StartupView | None
    started: float


def start_team(supervisor: Supervisor, plan: TeamPlan, launch: TeamLaunch) -> list[tuple[str, list[str]]]:
    """Start the monitor and the world, wait for the world's endpoints, then start the fusion centre
    (centralized estimation) and the robot processes, all told to connect to the world; returns the
    names and arguments (of ``ringtrack``) of the monitor and of the robot processes."""
    scenario, folder, view = plan.scenario, launch.folder, launch.view
    announce, handover = folder / "world-endpoints.json", folder / "display.handover"
    common = [str(folder / "scenario.toml"), "--run", f"{launch.run:08x}", "--monitor", "--exit-with-parent",
              "--lease", str(plan.lease)]
    common += [] if plan.secure is None else ["--secure", str(plan.secure.resolve())]
    common += ["--audit"] if plan.audit else []
    world_mode, others_mode = (["--mode", "router"], ["--mode", "client"]) if launch.topology == "star" else ([], [])
    if launch.start == "fork":
        supervisor.preload()  # it imports while the world and the monitor come up
    stop_rule = [] if plan.until_converged else ["--steps", str(scenario.max_steps)]
    grace = monitor_grace_s(plan.nemesis) if plan.nemesis else None
    world = ["world", *common, *world_mode, "--clock", plan.clock, "--rate", str(plan.rate), "--listen", launch.listen,
             "--announce", str(announce), "--lockstep-wait", str(plan.lockstep_wait), *stop_rule,
             *([] if grace is None else ["--monitor-grace", f"{grace:g}"])]
    monitor_flags = {True: ["--dashboard"], False: ["--no-dashboard"], None: []}[plan.dashboard]
    monitor_flags += ["--all-robots"] if plan.all_robots else []
    monitor_flags += [] if view is None else ["--display-handover", str(handover)]
    monitor_flags += [] if plan.foxglove is None else ["--foxglove", f"[{plan.foxglove[0]}]:{plan.foxglove[1]}"]
    monitor_flags += [] if plan.record is None else ["--record", str(plan.record.resolve())]
    say(view, "starting the world and the monitor")
    monitor = ["monitor", *common, *others_mode, "--connect-from", str(announce), "--log", str(launch.log_path),
               "--clock", plan.clock, *monitor_flags]
    with (folder / "monitor.stdout").open("wb") if plan.quiet else contextlib.nullcontext() as display:
        # Started at once: it comes up (and takes the start-up frame over) while the world does.
        supervisor.start("monitor", [*ROLE_COMMAND, *monitor], stdout=display)
    if launch.start == "fork":  # the launcher's imports are those of the world too
        supervisor.fork([("world", world)])
    else:
        supervisor.start("world", [*ROLE_COMMAND, *world])
    endpoints = supervisor.endpoints(announce, "world")
    processes = math.ceil(scenario.robots / plan.robots_per_process)
    listening = f"the world listens on {', '.join(endpoints)} after {time.perf_counter() - launch.started:.1f} s"
    if view is not None:  # said on the frame: a line above it would push its top off the screen
        say(view, f"{listening}; starting {processes} robot processes")
    elif not plan.quiet:
        err.print(f"spawn: {listening}; starting the others", highlight=False)
    connect = [flag for endpoint in endpoints for flag in ("--connect", endpoint)] + others_mode
    reply_wait = plan.lockstep_wait / 2 if plan.clock == "lockstep" else scenario.control.dt / plan.rate
    write_json(folder / "run.json", {"run": f"{launch.run:08x}", "connect": endpoints, "clock": plan.clock,
                                     "secure": None if plan.secure is None else str(plan.secure.resolve()),
                                     "reply_timeout": reply_wait, "lease_s": plan.lease})
    if scenario.centralized:
        supervisor.start("fusion", [*ROLE_COMMAND, "fusion", *common, *connect])
    robots = []
    for first in range(0, scenario.robots, plan.robots_per_process):
        last = min(first + plan.robots_per_process, scenario.robots) - 1
        ids = str(first) if first == last else f"{first}-{last}"
        robots.append((f"r{ids}", ["robot", *common, *connect, "--reply-timeout", str(reply_wait), "--id", ids]))
    if launch.start == "fork":
        supervisor.fork(robots)
    else:
        for name, argv in robots:
            supervisor.start(name, [*ROLE_COMMAND, *argv])
    if view is not None:
        say(view, "every process started; the monitor takes over this screen once it is up")
        view.started_all()
    return [("monitor", monitor), *robots]


def world_running(supervisor: Supervisor) -> bool:
    """Whether the world process is still running (the run is not over)."""
    return any(child.name == "world" for child in supervisor.running())


def unleash(plan: TeamPlan, supervisor: Supervisor, folder: Path, log_path: Path,
            started: list[tuple[str, list[str]]], start: str, critical: set[str]) -> Nemesis | None:
    """The nemesis of ``plan`` against the team just ``started`` (the monitor's and the robot
    processes' names and arguments; None: no plan). A restarted robot or monitor is a new process
    with its first process's arguments, named ``<name>@<n>`` for its n-th restart; a monitor's
    resumes the log (``--resume``) and draws no start-up frame. Once the nemesis kills one of the
    ``critical`` processes it empties that set: the others must notice on their own."""
    if not plan.nemesis:
        return None
    arguments = dict(started)
    handover = arguments["monitor"].index("--display-handover") if "--display-handover" in arguments["monitor"] \
        else None
    if handover is not None:
        del arguments["monitor"][handover:handover + 2]
    arguments["monitor"] = [*arguments["monitor"], "--resume"]
    restarts: dict[str, int] = {}

    def find(name: str) -> Child | None:
        running = [child for child in supervisor.running() if child.name.split("@")[0] == name]
        return running[-1] if running else None

    def send(child: object, number: int) -> int | None:
        assert isinstance(child, Child)
        with contextlib.suppress(ProcessLookupError):
            child.process.send_signal(number)
        return child.pid

    def restart(name: str) -> int:
        restarts[name] = restarts.get(name, 0) + 1
        role = (f"{name}@{restarts[name]}", arguments[name])
        if name == MONITOR:  # it prints its report where the first one would have
            with (folder / "monitor.stdout").open("ab") if plan.quiet else contextlib.nullcontext() as display:
                return supervisor.start(role[0], [*ROLE_COMMAND, *role[1]], stdout=display).pid
        child = supervisor.fork([role])[0] if start == "fork" else supervisor.start(role[0], [*ROLE_COMMAND, *role[1]])
        return child.pid

    def spare(child: object) -> None:
        assert isinstance(child, Child)
        supervisor.spared.add(child.pid)
        if child.name in critical:
            critical.clear()

    return Nemesis(plan.nemesis, folder, find, send, restart, spare, lambda: last_logged_step(log_path))


def reported(result: TeamResult, folder: Path, log_path: Path) -> TeamResult:
    """Write ``result`` to ``RUN_FOLDER/summary.json`` (a failed write is an error line and exit code
    1) and say on standard error why the run stopped early and what went wrong."""
    try:
        write_json(folder / "summary.json", result)
    except OutputError as error:
        err.print(f"ringtrack: error: {error}", highlight=False, markup=False)
        result.exit_code = result.exit_code or 1
    if result.stopped is not None:
        err.print(f"ringtrack: run {result.stopped}; every process stopped; log: {log_path}", highlight=False)
    if result.fenced_lives:
        err.print(f"spawn: {result.fenced_lives} robot processes stopped as a newer life of their id replaced them "
                  "(fenced; see the robots' stderr)", highlight=False)
    if result.distrust:
        err.print(f"ringtrack: error: this run's results cannot be trusted: {result.distrust}", highlight=False)
    return result


def startup_view(scenario: Scenario, clock: str, handover: Path) -> StartupView:
    """The start-up frame, drawn on stdout when the block is entered (:class:`tools.dashboard.startup.StartupView`)."""
    return StartupView(out, scenario, clock, handover)


def say(view: StartupView | None, note: str) -> None:
    """Show on the start-up frame (if any) what spawn is starting."""
    if view is not None:
        view.note = note


def secured(directory: Path, scenario: Scenario) -> str:
    """Check the team folder serves every participant of ``scenario`` (before anything starts) and
    return the endpoint the world listens on."""
    check_team(directory, sorted(scenario.participants()), scenario.robots)
    return SECURE_LOOPBACK_ANY_PORT


def stalled_at(log_path: Path, folder: Path) -> str:
    """What a stalled run waited for: the step after the last one logged, and, from the world's
    standard error, the robot its lockstep wait last named."""
    steps = len(read_log(log_path).steps) if log_path.is_file() else 0
    waiting = ""
    world_stderr = folder / "world.stderr"
    if world_stderr.is_file():
        named = [line for line in world_stderr.read_text(errors="replace").splitlines() if "waits for" in line]
        waiting = f"; {named[-1].removeprefix('ringtrack.world: ')}" if named else ""
    return f"after step {steps} (waiting for step {steps + 1}{waiting})"


def fenced(supervisor: Supervisor) -> list[Child]:
    """The robot processes that stopped because a newer life of their id replaced them: exit code
    :data:`agents.process.FENCED` and, as their last word, the line that says so. The fence did its
    work; they did not fail."""
    return [child for child in supervisor.crashed()
            if robot_index(child.name.split("@")[0]) is not None and child.process.returncode == FENCED
            and SUPERSEDED_MARK in child.stderr_tail(1)]


def failures(supervisor: Supervisor) -> dict[str, int | None]:
    """Exit code by name of every child that failed on its own (not a fenced life)."""
    excused = fenced(supervisor)
    return {child.name: child.process.returncode for child in supervisor.crashed() if child not in excused}


def _failure_lines(supervisor: Supervisor, log_path: Path) -> list[str]:
    """One line per child that crashed on its own, with the tail of its standard error (not the
    fenced ones: :func:`fenced`); a monitor that stopped because the run log could not be written
    (a full disk, whose stderr file cannot hold its message either) says which file and how many
    complete steps it holds."""
    lines = []
    excused = fenced(supervisor)
    for child in supervisor.crashed():
        if child in excused:
            continue
        if child.name == "monitor" and child.process.returncode == LogWriteError.exit_code:
            steps = len(read_log(log_path).steps) if log_path.is_file() else 0
            lines.append(f"ringtrack: error: {log_path}: the run log could not be written (disk full or not "
                         f"writable) after {steps} complete steps; the team was stopped")
            continue
        detail = child.stderr_tail()
        lines.append(f"{child.name} exited with {child.process.returncode}" + (f": {detail}" if detail else ""))
    return lines


def process_budget() -> int:
    """How many robot processes this machine can hold: 80 % of its available memory at
    ``PROCESS_MIB`` each, at most ``MAX_PROCESSES``."""
    try:
        meminfo = Path("/proc/meminfo").read_text()
        available_kib = int(next(line.split()[1] for line in meminfo.splitlines() if line.startswith("MemAvailable:")))
    except (OSError, StopIteration, ValueError):
        return MAX_PROCESSES
    return max(1, min(MAX_PROCESSES, int(0.8 * available_kib / 1024 / PROCESS_MIB)))


def startup_limit(processes: int) -> float:
    """Seconds a team of ``processes`` may take from the last start to its first step before spawn
    calls the start-up hung: generous (a 64-process team took 29 s on a loaded 2-core machine), so
    only a participant that never comes up reaches it."""
    return STALL_TIMEOUT_S + STARTUP_S_PER_PROCESS * processes


class FirstStep:
    """Notes when the run log first holds a step record: the team's start-up time."""

    def __init__(self, log_path: Path, started: float) -> None:
        self.log_path = log_path
        self.started = started
        self.after: float | None = None

    def __call__(self) -> None:
        if self.after is not None:
            return
        try:
            with self.log_path.open("rb") as log:
                head = log.read(65536)
        except OSError:  # not written yet (or gone: the run is over)
            return
        if b'"type":"step"' in head:
            self.after = time.perf_counter() - self.started

    def since(self) -> float | None:
        """Seconds since the first step was seen (None: not yet)."""
        return None if self.after is None else time.perf_counter() - self.started - self.after


def _result(scenario: Scenario, folder: Path, log_path: Path, clock: Clock, run: int, supervisor: Supervisor,
            wall_s: float, settle: int) -> TeamResult:
    """What the run folder's log and the senders' counts say of the run: its outcome, traffic,
    faults, memory, energy and speed, with its pids and wall time."""
    result = TeamResult(run=f"{run:08x}", clock=clock, folder=str(folder), log=str(log_path),
                        pids={child.name: child.pid for child in supervisor.children}, wall_s=wall_s)
    if not log_path.exists():
        return result
    log = read_log(log_path)
    if log.steps:
        result.outcome = summarise(history_from_log(log), settle=settle)
    end = log.end or {}
    senders = supervisor.senders_counts()
    if log.end is None:  # the monitor was lost: count traffic as its senders say they sent it
        traffic = [tuple(row) for counts in senders.values() for row in counts["sent"]]
        result.monitor_lost = True
        # robot-to-robot traffic is what the robots sent: unknown if one of them left no counts
        result.uncounted = sorted({robot_name(robot) for robot in range(scenario.robots)} - senders.keys())
    else:
        traffic = [tuple(row) for row in end.get("traffic", [])]
    by_category = totals_by_category(traffic)
    result.messages = {category: entry["messages"] for category, entry in by_category.items()}
    result.bytes = {category: entry["bytes"] for category, entry in by_category.items()}
    result.by_kind = totals_by_kind(traffic)
    result.monitor_equals_senders = end.get("consistent")
    result.faults = end.get("faults", {})
    result.rejected = end.get("rejected", {})
    result.rss_kib = end.get("rss_kib") or {name: counts["rss_kib"] for name, counts in senders.items()}
    result.end_reason = EndReason(end["reason"]) if "reason" in end else None
    result.id_collisions = end.get("notes", {}).get("id_collisions", 0)
    result.distrust = distrust(end) if log.end is not None else None
    result.energy = robot_energy(end.get("energy_j", {}), scenario.robots)
    if end.get("wall_s") and end.get("steps"):
        result.steps_per_s = end["steps"] / end["wall_s"]
    return result


def robot_energy(by_name: dict[str, list[float]], robots: int) -> EnergyReport | None:
    """The summary's energy section from an end record's ``energy_j`` (None unless every robot
    reported: a crashed robot's energy is unknown)."""
    names = [f"r{robot}" for robot in range(robots)]
    if not all(name in by_name for name in names):
        return None
    return energy_report([by_name[name][0] for name in names], [by_name[name][1] for name in names])
