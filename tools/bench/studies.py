"""``ringtrack bench studies``: how fast the studies run: trials per second on one worker and on
every core, the engine's seconds per trial alone and in batches, the decentralized EKF's cost
against the centralized one, and the wall time of whole studies (each beside its target:
:data:`TARGETS`; targets are reported, never asserted)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import msgspec

from ringtrack.agents import engine
from ringtrack.tools.bench.bench import BenchFailed, machine
from ringtrack.tools.output.console import err
from ringtrack.tools.studies.experiment import random_start_scenarios, stationary_experiment
from ringtrack.tools.studies.pool import worker_pool
from ringtrack.tools.studies.robustness import Cell, faults_experiment
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import Execution, Study, Task, available_cores, chunks, seed_range
from ringtrack.tools.team.launcher import PRELOADED
from ringtrack.world.scenario import Scenario, load_scenario

T = TypeVar("T")
MOVING = "authors-moving"
STATIONARY = "paper-stationary"
FAULT_DROPS = (0.0, 0.1, 0.2, 0.3, 0.5)
# Measured value -> (comparison, target): "<=" a ceiling, ">=" a floor.
TARGETS: dict[str, tuple[str, float]] = {
    "alone_s_per_trial": ("<=", 0.5),
    "batch_10_s_per_trial": ("<=", 0.15),
    "batch_100_s_per_trial": ("<=", 0.05),
    "decentralized_over_centralized": ("<=", 1.5),  # a trial each alone; batched ratios are reported beside it
    "faults_study_s": ("<=", 10.0),
    "stationary_sweep_s": ("<=", 3.0),
    "workers_2_speedup": (">=", 1.7),
    "robot_start_s": ("<=", 0.3),
}
# Throughput runs: name -> (scenario, strategy, estimation mode; None: a stationary target until converged).
THROUGHPUT: dict[str, tuple[str, str, str | None]] = {
    "stationary_n6_self": (STATIONARY, "self", None),
    "moving_decentralized_self": (MOVING, "self", "decentralized"),
    "moving_decentralized_belief": (MOVING, "belief", "decentralized"),
    "moving_centralized_self": (MOVING, "self", "centralized"),
}


@dataclass(frozen=True)
class Sizes:
    """How much a benchmark runs: moving-target steps (None: the scenario's 1300), throughput
    trials and their batch, the stationary step limit (None: the scenario's), the sweep's team sizes
    and trials, the faults study's trials, the trials of the speed-up study, and the rounds whose
    best a timing is (the per-trial timings; the faults study and the sweep take at most two)."""

    moving_steps: int | None
    throughput_trials: int
    throughput_batch: int
    stationary_steps: int | None
    sweep: range
    sweep_trials: int
    fault_trials: int
    speedup_trials: int
    repeats: int


FULL = Sizes(None, 20, 5, None, range(3, 31), 30, 10, 100, 3)
QUICK = Sizes(20, 2, 1, 60, range(3, 5), 1, 1, 4, 1)


@dataclass(frozen=True)
class BenchTask(Task):
    """A chunk of trials of one scenario (a stationary target's until they converged)."""

    scenario: Scenario


class BenchPart(msgspec.Struct, frozen=True):
    """Steps the chunk's batch ran."""

    steps: int


def bench_task(task: BenchTask) -> BenchPart:
    """Run one chunk of trials as an engine batch."""
    history = engine.run(task.scenario, task.seeds, until_converged=not task.scenario.moving, record_positions=False)
    return BenchPart(history.steps)


def pid_and_seconds(work: Callable[[T], object], task: T) -> tuple[int, float]:
    """Run ``work(task)`` and return the pid that ran it and its wall seconds there."""
    return os.getpid(), timed(lambda: work(task))


def two_process_ceiling(work: Callable[[T], object], task: T, repeats: int) -> float:
    """What two processes can gain here: twice the seconds one process takes for ``work(task)``
    over the seconds each of two takes when both run a copy at once (2.0: two free cores of their
    own; two hyperthreads of one core, or a host busy with other tenants, give less), no worker's
    start counted. Each timing is the best of ``repeats`` rounds, alone and together taking turns,
    in a warm pool of two (a round in which one worker took both copies is run again, up to
    ``4 * repeats`` rounds in all). ``work``
    must be a module's function (the pool's processes import it)."""
    alone: list[float] = []
    together: list[float] = []
    copies = [work, work], [task, task]
    with worker_pool(work.__module__, 2) as pool:
        list(pool.map(pid_and_seconds, *copies))  # both workers started and warm
        for _ in range(4 * repeats):
            alone.append(pool.submit(pid_and_seconds, work, task).result()[1])
            both = list(pool.map(pid_and_seconds, *copies))
            if both[0][0] != both[1][0]:
                together.append(max(seconds for _, seconds in both))
            if len(together) == repeats:
                break
    if not together:
        raise BenchFailed("bench studies: a pool of two workers never ran two tasks at once (is this process "
                          "allowed a single core?)")
    return 2 * min(alone) / min(together)


def scenario_of(base: str, strategy: str, mode: str | None, sizes: Sizes) -> Scenario:
    """The benchmarked scenario: a moving target's with ``mode`` estimation, or random starts of six
    robots for a stationary one."""
    if mode is None:
        return random_start_scenarios(base, 6, (strategy,), max_steps=sizes.stationary_steps)[strategy]
    return load_scenario(base, strategy=strategy, estimation=mode, max_steps=sizes.moving_steps)


def trials_per_s(scenario: Scenario, trials: int, batch: int, workers: int) -> float:
    """Trials per second of a study of ``trials`` trials of ``scenario`` in tasks of ``batch`` on
    ``workers`` local processes (pool start-up included)."""
    tasks = bench_tasks(scenario, trials, batch)
    started = time.perf_counter()
    run_study(Study("bench", {}, tasks, bench_task, BenchPart, batch), Execution(workers=workers, batch=batch))
    return trials / (time.perf_counter() - started)


def bench_tasks(scenario: Scenario, trials: int, batch: int) -> list[BenchTask]:
    """The tasks of a benchmarked study: ``trials`` trials of ``scenario`` (seeds 0..) in chunks of ``batch``."""
    return [BenchTask(seed_range(seeds), first, seeds, scenario) for first, seeds in chunks(list(range(trials)), batch)]


def engine_batch(scenario: Scenario, trials: int) -> Callable[[], object]:
    """One engine batch of ``trials`` trials of ``scenario``, to time."""
    return lambda: engine.run(scenario, list(range(trials)), record_positions=False)


def best_seconds(calls: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """The least wall seconds of each call over ``repeats`` rounds, the calls taking turns (a busy
    machine only ever slows a run down, and taking turns spreads its load over all of them)."""
    seconds: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            seconds[name].append(timed(call))
    return {name: min(values) for name, values in seconds.items()}


# A launcher's work, timed: import what it preloads, fork, and in the child build a decentralized
# robot's estimator (its first step's work) and report the seconds since the fork.
ROBOT_START = f"""
import importlib, os, sys, time
for name in {PRELOADED!r}:
    importlib.import_module(name)
from ringtrack.agents.estimation import Estimator
from ringtrack.world.scenario import load_scenario
scenario = load_scenario("{MOVING}", estimation="decentralized")
read, write = os.pipe()
forked = time.perf_counter()
if os.fork() == 0:
    estimator = Estimator(scenario.estimation, scenario.region, scenario.target)
    estimator.measure(scenario.start_positions(0)[:1], [3.0])
    os.write(write, repr(time.perf_counter() - forked).encode())
    os._exit(0)
os.close(write)
print(os.read(read, 64).decode())
os.wait()
"""


def robot_start_s() -> float:
    """Seconds from the fork of a robot process by a launcher (its modules preloaded) until it has
    built its estimator and measured once (a fresh interpreter runs :data:`ROBOT_START`)."""
    output = subprocess.run([sys.executable, "-c", ROBOT_START], capture_output=True, text=True, check=True)
    return float(output.stdout)


def timed(call: Callable[[], object]) -> float:
    """Wall seconds ``call`` took."""
    started = time.perf_counter()
    call()
    return time.perf_counter() - started


def studies_results(sizes: Sizes) -> dict[str, Any]:
    """Every measurement of ``bench studies`` at ``sizes`` (seconds, trials per second, ratios)."""
    cores = available_cores()
    with worker_pool(bench_task.__module__, 1) as pool:  # the fork server starts once a command: not timed
        pool.submit(os.getpid).result()
    throughput = {}
    for name, (base, strategy, mode) in THROUGHPUT.items():
        err.print(f"bench studies: {name}, {sizes.throughput_trials} trials on 1 and {cores} workers", highlight=False)
        scenario = scenario_of(base, strategy, mode, sizes)
        throughput[name] = {f"workers_{workers}": trials_per_s(scenario, sizes.throughput_trials,
                                                                sizes.throughput_batch, workers)
                            for workers in dict.fromkeys((1, cores))}
    err.print("bench studies: per-trial seconds alone and in batches of 10 and 100", highlight=False)
    decentralized = scenario_of(MOVING, "self", "decentralized", sizes)
    centralized = scenario_of(MOVING, "self", "centralized", sizes)
    batches = {"alone": 1, "batch_10": 10, "batch_100": 100}
    # each decentralized batch and the centralized one of its size take turns, so each ratio sees one load
    per_batch = best_seconds({f"{mode}_{label}": engine_batch(scenario, trials) for label, trials in batches.items()
                              for mode, scenario in (("decentralized", decentralized), ("centralized", centralized))},
                             sizes.repeats)
    per_trial = {f"{label}_s_per_trial": per_batch[f"decentralized_{label}"] / trials
                 for label, trials in batches.items()}
    ratios = {label: per_batch[f"decentralized_{label}"] / per_batch[f"centralized_{label}"] for label in batches}
    err.print("bench studies: the faults study, the stationary sweep and the speed-up of 2 workers", highlight=False)
    cells = [Cell(drop, 0, None) for drop in FAULT_DROPS]
    every_core = Execution(workers=cores)  # as the commands run by default
    studies = best_seconds({
        "faults": lambda: faults_experiment(MOVING, cells, sizes.fault_trials, 0, sizes.moving_steps,
                                            settle=min(300, decentralized.max_steps - 1), execution=every_core),
        "sweep": lambda: stationary_experiment(STATIONARY, list(sizes.sweep), sizes.sweep_trials, 0,
                                               execution=every_core, max_steps=sizes.stationary_steps),
    }, min(2, sizes.repeats))
    stationary = scenario_of(STATIONARY, "self", None, sizes)
    speedup_batch = max(1, sizes.speedup_trials // 10)
    # the best of two runs each, alternating (a busy machine only ever slows a run down)
    runs = [(workers, trials_per_s(stationary, sizes.speedup_trials, speedup_batch, workers))
            for _ in range(2) for workers in (1, 2)]
    one, two = (max(rate for count, rate in runs if count == workers) for workers in (1, 2))
    first_task = bench_tasks(stationary, sizes.speedup_trials, speedup_batch)[0]
    return {
        "benchmark": "studies",
        "machine": machine(),
        "moving_steps": decentralized.max_steps,
        "throughput_trials_per_s": throughput,
        **per_trial,
        "decentralized_over_centralized": ratios["alone"],
        "decentralized_over_centralized_batched": {label: ratios[label] for label in ("batch_10", "batch_100")},
        "faults_study_s": studies["faults"],
        "stationary_sweep_s": studies["sweep"],
        "workers_2_speedup": two / one,
        "two_process_ceiling": two_process_ceiling(bench_task, first_task, sizes.repeats),
        "speedup_trials": sizes.speedup_trials,
        "robot_start_s": min(robot_start_s() for _ in range(3)),
    }


def targets_met(results: dict[str, Any]) -> dict[str, bool]:
    """Whether each measured value with a target meets it."""
    return {name: results[name] <= target if way == "<=" else results[name] >= target
            for name, (way, target) in TARGETS.items()}
