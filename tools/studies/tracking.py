"""``ringtrack experiment tracking``: decentralized tracking against the centralized filter over many
scenarios (shipped, files, folders of generated ones), and against the posterior Cramér-Rao bound
(:mod:`world.bounds`) where the target is a random walk.

Every scenario runs each strategy with decentralized estimation, and as reference the scenario's own
strategy (``self`` where its own needs decentralized estimation) with the centralized EKF, all on
the same seeds: the same starts, target paths and range noise. A run's figures are those of
``experiment moving`` (:func:`tools.studies.experiment.moving_figures` of its exact
:class:`~tools.studies.experiment.StepTotals`) plus the RMSE of the robots' estimates and the bound,
summed in fixed point too, so they do not depend on batching or workers.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import matplotlib.pyplot as plt
import msgspec
import numpy as np

from ringtrack.agents import engine
from ringtrack.agents.strategy import REGISTRY, StrategyError, check_strategy, strategy_class
from ringtrack.tools.output.console import UsageError
from ringtrack.tools.output.files import struct_columns
from ringtrack.tools.studies.experiment import (
    FIXED_POINT,
    StepTotals,
    check_settle,
    combined,
    exact_sum,
    fixed_point_sums,
    moving_figures,
    reference_strategy,
    step_totals,
    strategy_labels,
    strategy_name,
)
from ringtrack.tools.studies.figures import colour, drawn
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import IN_PROCESS, Execution, Study, Task, chunks, seed_range
from ringtrack.world.bounds import random_walk_bound
from ringtrack.world.geometry import FloatArray
from ringtrack.world.metrics import settled_mean, target_error
from ringtrack.world.scenario import Scenario, load_scenario
from ringtrack.world.target import RandomWalk

SETTLE = 300  # steps left out of the means unless --settle says otherwise (capped below a run's length)


def decentralized_strategies() -> list[str]:
    """Every registered strategy that runs with decentralized estimation (:data:`REGISTRY` order)."""
    return [name for name in REGISTRY if strategy_class(name).estimation in (None, "decentralized")]


class TrackingRow(msgspec.Struct, frozen=True, kw_only=True):
    """One strategy and estimation mode on one scenario over the study's trials (a row of ``experiment
    tracking --csv``): the scenario's name, target ``motion``, team size, ``steps`` run and the
    ``settle`` steps the means leave out; settled means over robots, steps and trials of Terr
    (metres) and true Cerr (degrees), robot-to-robot messages per robot-step; ``rmse`` (metres) the
    root of the mean squared distance from each robot's estimate to the target; ``terr_ratio`` Terr
    over the centralized row's on the same scenario. A random-walk target's rows add ``crb_rmse``
    (metres), the root of the settled mean of the posterior Cramér-Rao bound ``trace(J^-1)`` along
    each trial's path from its robots' positions (:func:`world.bounds.random_walk_bound`), and
    ``terr_over_crb`` and ``rmse_over_crb`` (like for like: RMSE against the bound); other rows have
    None there."""

    scenario: str
    motion: str
    robots: int
    strategy: str
    estimation: str
    trials: int
    steps: int
    settle: int
    terr_mean: float | None
    cerr_mean_deg: float | None
    robot_messages_per_robot_step: float
    rmse: float | None
    terr_ratio: float | None
    crb_rmse: float | None
    terr_over_crb: float | None
    rmse_over_crb: float | None


TERR_GOAL = 1.2  # a decentralized run meets the goal at most this many times the centralized Terr ...
# ... on at most the centralized team's robot-to-robot messages per robot-step, true Cerr within:
CERR_GOAL_DEG = 1.0  # degrees of the centralized team's


class TrackingVerdict(msgspec.Struct, frozen=True, kw_only=True):
    """How one decentralized strategy fared over the study's scenarios: on how many of them
    (``met``) its Terr is at most ``TERR_GOAL`` times the centralized filter's on at most the
    centralized team's messages per robot-step, on how many its true Cerr is within ``CERR_GOAL_DEG``
    of that team's (``cerr_met``), and the worst Terr ratio, message ratio and Cerr excess (degrees)
    with the scenarios where they fell."""

    strategy: str
    scenarios: int
    met: int
    cerr_met: int
    worst_terr_ratio: float | None
    worst_terr_scenario: str
    worst_message_ratio: float | None
    worst_message_scenario: str
    worst_cerr_excess_deg: float | None
    worst_cerr_scenario: str


class TrackingStudy(msgspec.Struct, frozen=True, kw_only=True):
    """What ``experiment tracking`` came to (its JSON): the ``scenarios`` (as given, folders opened
    into their files), the decentralized ``strategies`` and ``labels`` naming them, on seeds ``seed ..
    seed + trials - 1``; ``rows`` a :class:`TrackingRow` per scenario and run, the centralized
    reference last on each scenario. ``wall_s``: seconds the study took."""

    experiment: Literal["tracking"] = "tracking"
    scenarios: list[str]
    trials: int
    seed: int
    steps: int | None
    settle: int
    strategies: list[str]
    labels: dict[str, str]
    wall_s: float
    rows: list[TrackingRow]
    verdicts: list[TrackingVerdict]


TRACKING_COLUMNS = struct_columns(TrackingRow)


def scenario_sources(given: Sequence[str]) -> list[str]:
    """Shipped names and TOML files as given, a folder as its ``*.toml`` files in name order."""
    sources = []
    for value in given:
        path = Path(value)
        if path.is_dir():
            found = sorted(str(file) for file in path.glob("*.toml"))
            if not found:
                raise UsageError(f"{value}: a folder without .toml files; give scenario files, a folder of them "
                                 "(ringtrack scenarios generate) or shipped names")
            sources += found
        else:
            sources.append(value)
    return sources


@dataclass(frozen=True)
class TrackingTask(Task):
    """A chunk of the trials of one run (a scenario with a strategy and an estimation mode)."""

    scenario: Scenario


class TrackingPart(msgspec.Struct, frozen=True):
    """What a :class:`TrackingTask` came to: the chunk's :class:`StepTotals`, and per step the fixed
    point sums over its trials of the robots' mean squared estimate error (m^2) and, for a random
    walk, of the bound ``trace(J^-1)`` (m^2; None: no bound)."""

    totals: StepTotals
    squared: list[int]
    bound: list[int] | None


def bound_of(scenario: Scenario, positions: FloatArray, targets: FloatArray) -> FloatArray | None:
    """The PCRB ``trace(J^-1)`` (m^2, per step and trial) of the scenario's true sensing along the
    recorded ``positions`` (K, T, N, 2) and ``targets`` (K, T, 2), metres; None unless the target is
    a random walk (F = I, Q its step covariance) measured with noise."""
    target, sigma = scenario.spec.target, scenario.spec.sensing.range_sigma
    if not isinstance(target, RandomWalk) or sigma == 0:
        return None
    return random_walk_bound(positions, targets, sigma, target.step_covariance(scenario.control.dt),
                             scenario.estimation.prior_variance, scenario.spec.sensing.range)


def tracking_task(task: TrackingTask) -> TrackingPart:
    """Run a chunk of trials as one batch, recording positions and estimates."""
    history = engine.run(task.scenario, task.seeds, record_positions=True)
    assert history.estimates is not None and history.positions is not None  # recorded
    bound = bound_of(task.scenario, history.positions, history.targets)
    return TrackingPart(step_totals(history, slice(None)),
                        fixed_point_sums(target_error(history.estimates, history.targets, squared=True)),
                        None if bound is None else fixed_point_sums(bound))


def run_scenario(source: str, strategy: str, mode: str, steps: int | None) -> Scenario:
    """The scenario at ``source`` with ``strategy`` and estimation ``mode``, ``steps`` long."""
    scenario = load_scenario(source, strategy=strategy, estimation=mode, max_steps=steps)
    try:
        check_strategy(scenario)
    except StrategyError as error:
        raise UsageError(f"--strategies: {error}") from None
    return scenario


def tracking_experiment(sources: Sequence[str], trials: int, seed: int, strategies: Sequence[str] | None = None,
                        steps: int | None = None, settle: int | None = None,
                        execution: Execution = IN_PROCESS) -> TrackingStudy:
    """Run every strategy (default :func:`decentralized_strategies`) with decentralized estimation and
    the centralized reference on each scenario of ``sources`` (:func:`scenario_sources`), seeds
    ``seed .. seed + trials - 1``, ``steps`` steps (default each scenario's), means from step
    ``settle`` on (default ``SETTLE`` capped below a run's length), in tasks of ``execution.trials_per_task()``
    trials (:mod:`tools.studies.runner`)."""
    if trials < 1:
        raise UsageError(f"--trials {trials}: give at least 1 trial")
    started = time.perf_counter()
    compared = list(strategies) if strategies is not None else decentralized_strategies()
    seeds = list(range(seed, seed + trials))
    runs: list[tuple[str, Scenario, str, str, int]] = []  # (scenario name, scenario, strategy, mode, settle)
    given = scenario_sources(sources)
    for source in given:
        base = load_scenario(source, max_steps=steps)
        if any(name == base.name for name, *_ in runs):
            raise UsageError(f"SCENARIO {source}: another scenario given is named {base.name!r} too; give each once")
        length = base.max_steps
        if settle is not None:
            check_settle(settle, length, base.name)
        settled = min(SETTLE, length - 1) if settle is None else settle
        plan = [(strategy, "decentralized") for strategy in compared] + [(reference_strategy(base), "centralized")]
        runs += [(base.name, run_scenario(source, strategy, mode, steps), strategy, mode, settled)
                 for strategy, mode in plan]
    batch = execution.trials_per_task()
    parts = chunks(seeds, batch)
    tasks = [TrackingTask(f"{name} {strategy}+{mode} {seed_range(part)}", first, part, scenario)
             for name, scenario, strategy, mode, _ in runs for first, part in parts]
    parameters = {"scenarios": given, "trials": trials, "seed": seed, "strategies": compared,
                  "steps": steps, "settle": settle}
    results = run_study(Study("tracking", parameters, tasks, tracking_task, TrackingPart, batch), execution)
    rows = [tracking_row(name, scenario, strategy, mode, settled, results[index * len(parts):(index + 1) * len(parts)])
            for index, (name, scenario, strategy, mode, settled) in enumerate(runs)]
    rows = with_ratios(rows)
    names = [strategy_name(s) for s in compared]
    return TrackingStudy(scenarios=given, trials=trials, seed=seed, steps=steps,
                         settle=SETTLE if settle is None else settle, strategies=names,
                         labels=strategy_labels(list(dict.fromkeys(strategy for _, _, strategy, _, _ in runs))),
                         wall_s=time.perf_counter() - started, rows=rows,
                         verdicts=[tracking_verdict(rows, name) for name in names])


def tracking_verdict(rows: Sequence[TrackingRow], strategy: str) -> TrackingVerdict:
    """The :class:`TrackingVerdict` of ``strategy``'s decentralized rows against each scenario's
    centralized row."""
    central = {row.scenario: row for row in rows if row.estimation == "centralized"}
    terrs: list[tuple[float | None, str]] = []
    messages: list[tuple[float | None, str]] = []
    excesses: list[tuple[float | None, str]] = []  # true Cerr over the centralized team's, degrees
    for row in rows:
        if row.strategy != strategy or row.estimation != "decentralized":
            continue
        reference = central[row.scenario]
        terrs.append((row.terr_ratio, row.scenario))
        messages.append((_ratio(row.robot_messages_per_robot_step, reference.robot_messages_per_robot_step),
                         row.scenario))
        excesses.append((None if row.cerr_mean_deg is None or reference.cerr_mean_deg is None
                         else row.cerr_mean_deg - reference.cerr_mean_deg, row.scenario))

    def worst(judged: list[tuple[float | None, str]]) -> tuple[float | None, str]:
        known = [(value, scenario) for value, scenario in judged if value is not None]
        return max(known) if known else (None, "")

    met = sum(terr is not None and terr <= TERR_GOAL and (sent is None or sent <= 1.0)
              for (terr, _), (sent, _) in zip(terrs, messages, strict=True))
    cerr_met = sum(excess is not None and excess <= CERR_GOAL_DEG for excess, _ in excesses)
    (terr, terr_at), (message, messages_at), (excess, excess_at) = worst(terrs), worst(messages), worst(excesses)
    return TrackingVerdict(strategy=strategy, scenarios=len(terrs), met=met, cerr_met=cerr_met,
                           worst_terr_ratio=terr, worst_terr_scenario=terr_at, worst_message_ratio=message,
                           worst_message_scenario=messages_at, worst_cerr_excess_deg=excess,
                           worst_cerr_scenario=excess_at)


def _root_mean(sums: list[int], trials: int, settle: int) -> float | None:
    """The root of the settled mean of per-step fixed-point sums over ``trials`` of m^2: metres."""
    mean = settled_mean(np.array(sums, dtype=float) / (FIXED_POINT * trials), settle)
    return None if mean is None else math.sqrt(mean)


def tracking_row(name: str, scenario: Scenario, strategy: str, mode: str, settle: int,
                 parts: list[TrackingPart]) -> TrackingRow:
    """A run's row from its chunks' parts (ratios to the centralized row: :func:`with_ratios`)."""
    totals = combined([part.totals for part in parts])
    figures = moving_figures(totals, scenario.robots, settle, mode)
    rmse = _root_mean(exact_sum([part.squared for part in parts]), totals.trials, settle)
    bounds = [part.bound for part in parts if part.bound is not None]
    crb = _root_mean(exact_sum(bounds), totals.trials, settle) if bounds else None
    return TrackingRow(
        scenario=name, motion=str(scenario.spec.target.__struct_config__.tag), robots=scenario.robots,
        strategy=strategy_name(strategy), estimation=mode, trials=totals.trials, steps=len(totals.polls),
        settle=settle, terr_mean=figures.terr_mean, cerr_mean_deg=figures.cerr_mean_deg,
        robot_messages_per_robot_step=figures.robot_messages_per_robot_step, rmse=rmse, terr_ratio=None,
        crb_rmse=crb, terr_over_crb=_ratio(figures.terr_mean, crb), rmse_over_crb=_ratio(rmse, crb))


def _ratio(value: float | None, reference: float | None) -> float | None:
    return None if value is None or not reference else value / reference


def with_ratios(rows: list[TrackingRow]) -> list[TrackingRow]:
    """The rows with ``terr_ratio``: Terr over the centralized row's on the same scenario."""
    central = {row.scenario: row.terr_mean for row in rows if row.estimation == "centralized"}
    return [msgspec.structs.replace(row, terr_ratio=_ratio(row.terr_mean, central[row.scenario])) for row in rows]


def plot_tracking(result: TrackingStudy, path: Path) -> None:
    """Terr over the centralized Terr (y) against robot-to-robot messages per robot-step (x), a point
    per scenario and decentralized strategy, the centralized reference at y = 1."""
    figure, axis = plt.subplots(figsize=(6.5, 4.5), layout="constrained")
    for index, strategy in enumerate(result.strategies):
        rows = [row for row in result.rows if row.strategy == strategy and row.estimation == "decentralized"]
        axis.plot([row.robot_messages_per_robot_step for row in rows], [drawn(row.terr_ratio) for row in rows],
                  "o", color=colour(index), label=f"{result.labels[strategy]} (decentralized)")
    central = [row for row in result.rows if row.estimation == "centralized"]
    axis.axhline(1.0, color="black", linestyle="--", linewidth=1, label="centralized EKF (reference)")
    axis.plot([row.robot_messages_per_robot_step for row in central], [1.0] * len(central), "x", color="black")
    axis.axhline(TERR_GOAL, color="grey", linestyle=":", linewidth=1, label=f"{TERR_GOAL:g} x centralized (the goal)")
    axis.set_yscale("log")  # ratios: 1.1 and 9 both legible
    axis.set_xlabel("robot-to-robot messages per robot-step (constant: 4)")
    axis.set_ylabel("Terr / centralized Terr (log scale)")
    axis.set_title(f"{len(central)} scenarios, {result.trials} trials each, means from step {result.settle} "
                   "(or below a shorter run)", fontsize=10)
    axis.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)

