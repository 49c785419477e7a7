"""``ringtrack bench``: speed measurements reported as a rich table and JSON (never timed tests).

* ``engine``: the in-process engine, one run and batches of trials;
* ``emulator``: lockstep steps per second of a multi-process team over Zenoh, start-up time, wire
  bytes per message kind, resident memory per robot process;
* ``latency``: the neighbour round trip (a poll's request and reply) between two robot processes;
* ``suite``: all of them on the configurations the README reports.

Every result carries the machine's core count and the library versions it depends on.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path
from typing import Any, Literal

import msgspec
from rich.console import Console
from rich.progress import TaskID

from ringtrack.agents import engine
from ringtrack.agents.strategy import StrategyError, check_strategy, strategy_for
from ringtrack.agents.team import run_team
from ringtrack.bus.keys import new_run_id
from ringtrack.bus.security import create_team
from ringtrack.tools.bench.latency import endpoints_path
from ringtrack.tools.bench.wire import UNSHARE, WireRun
from ringtrack.tools.output.console import UsageError, err, progress_bar
from ringtrack.tools.studies.experiment import STRATEGIES, StationaryStudy, stationary_experiment
from ringtrack.tools.team.plan import TeamPlan, TeamResult
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.tools.team.supervisor import Supervisor
from ringtrack.world.scenario import Scenario, load_scenario

LATENCY_COMMAND = [sys.executable, "-m", "ringtrack.tools.bench.latency"]
MESSAGE_KINDS = ("request", "reply", "measurement", "command")

# The suite's emulator configurations: (robots, robots per process, steps, repeats). The teams its
# ratios are taken from run three times and report the median: one run of a large team lasts a few
# seconds, and on a shared machine two such runs minutes apart differed by a fifth.
SUITE_TEAMS = ((6, 1, 1000, 3), (24, 1, 500, 1), (64, 1, 300, 3), (64, 16, 300, 3), (256, 16, 100, 3))


def machine() -> dict[str, Any]:
    """Core count, Python and library versions that a benchmark result depends on."""
    versions = {name: metadata.version(name) for name in ("numpy", "eclipse-zenoh", "msgspec", "cryptography")}
    return {
        "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "versions": versions,
    }


# ---------------------------------------------------------------------------------------- engine
PROGRESS_EVERY = 50  # steps between progress updates (a batch that converges early jumps to its end)


class EngineProgress:
    """The parts of ``bench engine`` as progress bars on stderr, counted in batch-steps (a batch of
    trials stops at its last trial's convergence, so a bar jumps when a batch ends early); nothing is
    shown when ``console`` (default stderr) is not a terminal."""

    def __init__(self, steps: int, console: Console = err) -> None:
        self.steps = steps  # per batch
        self.bar = progress_bar(console, disable=not console.is_terminal)
        self.task: TaskID | None = None
        self.done: dict[tuple[int, str], int] = {}

    def part(self, label: str, batches: int) -> None:
        """End the current bar and start one for ``batches`` batches."""
        self.close()
        self.task, self.done = self.bar.add_task(label, total=batches * self.steps), {}

    def on_step(self, robots: int, strategy: str, step: int) -> None:
        """The experiments' progress callback: batch (``robots``, ``strategy``) has run ``step`` steps."""
        self.done[robots, strategy] = step
        if self.task is not None and step % PROGRESS_EVERY == 0:
            self.bar.update(self.task, completed=sum(self.done.values()))

    def close(self) -> None:
        if self.task is not None:
            self.bar.update(self.task, completed=self.bar.tasks[self.task].total)


PROTOCOL_STEPS = 1000  # steps of the team of robot protocols in one process (agents.team)


def engine_results(trials: int, sizes: list[int], console: Console = err) -> dict[str, object]:
    """One run of ``paper-stationary`` (all ``control.max_steps`` steps), its team of robot
    protocols in one process with no bus (:func:`agents.team.run_team`, ``PROTOCOL_STEPS``), the ``trials``-trial
    two-strategy experiment for N = 6, and the sweep over ``sizes``: steps per second, wall seconds
    and how many runs converged. Progress goes to ``console`` (:class:`EngineProgress`)."""
    if trials < 1:
        raise UsageError(f"--trials {trials}: give at least 1")
    scenario = load_scenario("paper-stationary")
    progress = EngineProgress(scenario.max_steps, console)
    with progress.bar:
        progress.part(f"one run, N = {scenario.robots}", 1)
        name = strategy_for(scenario.strategy).name
        started = time.perf_counter()
        history = engine.run(scenario, steps=scenario.max_steps, record_positions=False,
                             on_step=lambda step: progress.on_step(scenario.robots, name, step))
        elapsed = time.perf_counter() - started
        team_started = time.perf_counter()
        team = run_team(scenario, PROTOCOL_STEPS, new_run_id())
        team_elapsed = time.perf_counter() - team_started
        progress.part(f"experiment N = 6, {trials} trials x 2", len(STRATEGIES))
        experiment = stationary_experiment("paper-stationary", [6], trials, 0)
        progress.part(f"sweep N = {sizes[0]}..{sizes[-1]}, {trials} trials x 2", len(STRATEGIES) * len(sizes))
        sweep = stationary_experiment("paper-stationary", sizes, trials, 0)
        progress.close()

    def converged(result: StationaryStudy) -> int:
        return sum(entry.converged for entry in result.summary)

    return {
        "single_run": {"robots": scenario.robots, "steps": history.steps, "steps_per_s": history.steps / elapsed},
        "protocol_alone": {"robots": scenario.robots, "steps": PROTOCOL_STEPS,
                           "steps_per_s": PROTOCOL_STEPS / team_elapsed,
                           "messages_per_step": team.messages / PROTOCOL_STEPS},
        "experiment_n6": {"trials": trials, "runs": 2 * trials, "converged": converged(experiment),
                          "wall_s": experiment.wall_s},
        "sweep": {"robots": f"{sizes[0]}..{sizes[-1]}", "trials": trials, "runs": 2 * trials * len(sizes),
                  "converged": converged(sweep), "wall_s": sweep.wall_s},
    }


# -------------------------------------------------------------------------------------- emulator
class BenchFailed(RuntimeError):
    """A benchmarked team did not complete."""


def emulator_row(robots: int, steps: int, strategy: str = "self", repeat: int = 1, dashboard: str = "off",
                 runs: Path = Path("runs"), robots_per_process: int = 1,
                 topology: Literal["mesh", "star"] | None = None, secure: str = "off") -> dict:
    """Run ``repeat`` lockstep teams of ``robots`` robots for ``steps`` steps and report medians of
    steps per second and start-up seconds (spawn to the first logged step), payload bytes per message
    kind and resident memory (MiB) of the largest robot process. With ``dashboard`` "compare"
    alternately without and with the dashboard; with ``secure`` "compare" alternately plain and
    secure (each run in a private network namespace when :func:`isolation_works`, which also gives
    the bytes on the wire per message)."""
    if repeat < 1:
        raise UsageError(f"--repeat {repeat}: give at least 1")
    if steps < 1:
        raise UsageError(f"--steps {steps}: give at least 1")
    if dashboard == "compare" and secure == "compare":
        raise UsageError("--dashboard compare --secure compare: compare one thing at a time")
    if secure == "compare":
        variants = [(dashboard == "on", False), (dashboard == "on", True)]
    elif dashboard == "compare":
        variants = [(False, secure == "on"), (True, secure == "on")]
    else:
        variants = [(dashboard == "on", secure == "on")]
    isolated = secure == "compare" and dashboard == "off" and isolation_works()
    scenario = load_scenario("paper-stationary", robots=robots, strategy=strategy, max_steps=steps)
    try:
        check_strategy(scenario)  # a strategy that needs another estimation mode: one line, before any team
    except StrategyError as error:
        raise UsageError(f"--strategy {strategy}: {error}") from None
    results: dict[tuple[bool, bool], list[WireRun]] = {variant: [] for variant in variants}
    startups: list[float] = []
    with tempfile.TemporaryDirectory(prefix="ringtrack-bench-") as scratch:
        team = Path(scratch) / "team"
        if any(with_security for _, with_security in variants):
            create_team(team, robots)
        for attempt in range(repeat):
            for with_dashboard, with_security in variants:
                err.print(f"{robots} robots ({robots_per_process} per process), {steps} lockstep steps, dashboard "
                          f"{'on' if with_dashboard else 'off'}, {'secure' if with_security else 'plain'}"
                          f"{', own network namespace' if isolated else ''} (run {attempt + 1}/{repeat}) ...")
                secured = team if with_security else None
                if isolated:
                    measured = isolated_run(scenario, runs, secured, Path(scratch))
                else:
                    measured = WireRun(spawn_team(TeamPlan(
                        scenario=scenario, clock="lockstep", runs=runs, dashboard=with_dashboard, quiet=True,
                        robots_per_process=robots_per_process, topology=topology, secure=secured)))
                if measured.team.exit_code != 0 or measured.team.steps_per_s is None:
                    raise BenchFailed(f"the {robots}-robot run failed: {measured.team.failures}; see "
                                      f"{measured.team.folder}")
                results[(with_dashboard, with_security)].append(measured)
                if measured.team.startup_s is not None:
                    startups.append(measured.team.startup_s)
    first = variants[0]
    result = results[first][-1].team
    # Every participant reports its process's peak RSS: participants of one process report the same.
    robot_rss = [kib for name, kib in result.rss_kib.items() if name.startswith("r")]
    row: dict[str, Any] = {
        "robots": robots,
        "robots_per_process": robots_per_process,
        "topology": result.topology,
        "steps": result.outcome.steps if result.outcome else 0,
        "secure": first[1],
        "steps_per_s": speed(results[first]),
        "runs_steps_per_s": [run.team.steps_per_s for run in results[first]],
        "startup_s": statistics.median(startups) if startups else None,
        "bytes_per_message": payload_bytes(result),
        "robot_process_rss_mib": max(robot_rss) / 1024 if robot_rss else None,
        "world_rss_mib": result.rss_kib.get("world", 0) / 1024,
        "run_folder": result.folder,
    }
    if dashboard == "compare":
        drawn = results[variants[1]]
        row["runs_steps_per_s_with_dashboard"] = [run.team.steps_per_s for run in drawn]
        row["steps_per_s_with_dashboard"] = speed(drawn)
        row["dashboard_cost"] = 1.0 - row["steps_per_s_with_dashboard"] / row["steps_per_s"]
    if secure == "compare":
        plain, secured_runs = results[variants[0]], results[variants[1]]
        row["runs_steps_per_s_secure"] = [run.team.steps_per_s for run in secured_runs]
        row["steps_per_s_secure"] = speed(secured_runs)
        row["security_cost"] = 1.0 - row["steps_per_s_secure"] / row["steps_per_s"]
        row["bytes_per_message_secure"] = payload_bytes(secured_runs[-1].team)
        row["wire_bytes_per_message"] = (
            {"plain": statistics.median(run.wire_bytes_per_message for run in plain),
             "secure": statistics.median(run.wire_bytes_per_message for run in secured_runs)} if isolated else None)
        row["startup_wire_bytes"] = (
            {"plain": statistics.median(run.startup_wire_bytes or 0 for run in plain),
             "secure": statistics.median(run.startup_wire_bytes or 0 for run in secured_runs)} if isolated else None)
    return row


def speed(runs: list[WireRun]) -> float:
    """The median steps per second of ``runs`` (every one of which stepped)."""
    return statistics.median(run.team.steps_per_s or 0.0 for run in runs)


def payload_bytes(result: TeamResult) -> dict[str, float]:
    """Payload bytes per message of each kind in a team's result."""
    return {kind: entry["bytes"] / entry["messages"] for kind, entry in sorted(result.by_kind.items())
            if entry["messages"]}


def isolation_works() -> bool:
    """Whether this machine lets us run a team in a private network namespace (``unshare``)."""
    try:
        return subprocess.run([*UNSHARE, "true"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def isolated_run(scenario: Scenario, runs: Path, secure: Path | None, scratch: Path) -> WireRun:
    """One lockstep team in a private network namespace (``tools/bench/wire.py``): its summary with
    ``wire_bytes_per_message``, the bytes its loopback carried while stepping divided by the
    messages of the run, and ``startup_wire_bytes``, those before its first step."""
    scenario_path, out = scratch / "scenario.toml", scratch / "isolated.json"
    scenario_path.write_bytes(scenario.to_toml())
    out.unlink(missing_ok=True)
    command = [*UNSHARE, sys.executable, "-m", "ringtrack.tools.bench.wire", str(out), str(scenario_path),
               str(runs.resolve()), *([str(secure)] if secure is not None else [])]
    completed = subprocess.run(command, capture_output=True, text=True)
    if completed.returncode != 0 or not out.exists():
        raise BenchFailed(f"the isolated run failed: {completed.stderr.strip()[-300:]}")
    return msgspec.json.decode(out.read_bytes(), type=WireRun)


# --------------------------------------------------------------------------------------- latency
def neighbour_round_trip(rounds: int, warmup: int) -> dict[str, object]:
    """Time ``rounds`` polls of one robot process by another (after ``warmup`` untimed ones):
    round-trip median, p99 and mean in microseconds, and CPU microseconds per round trip on each side."""
    if rounds < 1 or warmup < 0:
        raise UsageError(f"--rounds {rounds} --warmup {warmup}: give at least 1 round and no negative warm-up")
    err.print(f"{rounds} neighbour round trips between two robot processes ...")
    run = f"{new_run_id():08x}"
    with tempfile.TemporaryDirectory(prefix="ringtrack-latency-") as directory:
        folder = Path(directory)
        sides = {side: folder / f"{side}.json" for side in ("echo", "ping")}
        common = ["--run", run, "--rounds", str(rounds), "--warmup", str(warmup)]
        with Supervisor(folder) as supervisor:
            supervisor.start("echo", [*LATENCY_COMMAND, "echo", *common, "--result", str(sides["echo"])])
            connect = [flag for endpoint in supervisor.endpoints(endpoints_path(sides["echo"]), "echo")
                       for flag in ("--connect", endpoint)]
            supervisor.start("ping", [*LATENCY_COMMAND, "ping", *common, "--result", str(sides["ping"]), *connect])
            supervisor.wait(critical=frozenset({"echo", "ping"}))
            if supervisor.failed():
                child = supervisor.failed()[0]
                raise BenchFailed(f"the {child.name} process failed: {child.stderr_tail()}")
        ping, echo = (json.loads(sides[side].read_text()) for side in ("ping", "echo"))
    round_trips = sorted(ping["round_trips_s"])
    return {
        "rounds": rounds,
        "median_us": statistics.median(round_trips) * 1e6,
        "p99_us": round_trips[min(len(round_trips) - 1, int(0.99 * len(round_trips)))] * 1e6,
        "mean_us": statistics.fmean(round_trips) * 1e6,
        "cpu_us_per_round_trip": {"requester": ping["cpu_s"] / rounds * 1e6, "responder": echo["cpu_s"] / rounds * 1e6},
    }


# ----------------------------------------------------------------------------------------- suite
# The team configurations whose speed the suite reports relative to its own round trip.
RATIO_TEAMS = ((6, 1), (64, 1), (64, 16), (256, 16))


def suite_ratios(results: dict[str, Any]) -> dict[str, Any]:
    """Figures of one suite run that machine noise largely cancels from: for each team of
    ``RATIO_TEAMS``, how many neighbour round trips (the run's own median) one lockstep step takes;
    the same for the six robot protocols alone (:func:`agents.team.run_team`, one core and no bus:
    the floor under the team of six); the start-up of 64 robots one per process (seconds); resident
    memory of a robot process (MiB, one robot and 16 robots per process)."""
    round_trip_s = results["latency"]["median_us"] * 1e-6
    rows = {(row["robots"], row["robots_per_process"]): row for row in results["emulator"]}
    ratios: dict[str, Any] = {"round_trip_us": results["latency"]["median_us"], "round_trips_per_step": {}}
    for robots, per_process in RATIO_TEAMS:
        row = rows.get((robots, per_process))
        if row is not None:
            ratios["round_trips_per_step"][f"{robots}x{per_process}"] = 1.0 / (row["steps_per_s"] * round_trip_s)
    protocol = results["engine"]["protocol_alone"]
    ratios["protocol_alone_round_trips_per_step"] = 1.0 / (protocol["steps_per_s"] * round_trip_s)
    if (64, 1) in rows:
        ratios["startup_64_s"] = rows[64, 1]["startup_s"]
    for per_process in (1, 16):
        memory = [row["robot_process_rss_mib"] for key, row in rows.items() if key[1] == per_process
                  and row["robot_process_rss_mib"]]
        if memory:
            ratios[f"robot_process_rss_mib_{per_process}_per_process"] = max(memory)
    return ratios
