"""``ringtrack experiment faults``: robustness curves. How convergence, communication, energy and
(moving targets) tracking degrade as links get worse, per strategy, over a sweep of drop rates,
partition outages and communication ranges, on the same seeded random starts; ``--verify K``
re-runs K of the runs as lockstep teams over Zenoh and checks they equal the engine's.

A *cell* is one value of each swept quantity; a *variant* one strategy (and, for a moving target,
one estimation mode). Trial t of every cell and variant uses seed ``SEED + t`` for its start, noise
and fault draws (:func:`agents.engine.fault_seeds`). An outage of L steps cuts the ring into two
halves: links ``(N/2 - 1, N/2)`` and ``(N - 1, 0)`` are down for steps ``OUTAGE_START ..
OUTAGE_START + L - 1``. Costs (robot-to-robot messages, bytes, radio energy) and the fault layer's
counts of a stationary-target run count steps 1..Ctime (every step run when it did not converge), as
the trial run alone would; of a moving-target run every step, with Cerr (true, degrees) and Terr
(metres) averaged from ``--settle`` on.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np
from msgspec import UNSET, UnsetType

from ringtrack.agents import engine
from ringtrack.tools.output.files import struct_columns
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.tools.studies.experiment import check_settle, strategy_labels
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import IN_PROCESS, Execution, Study, Task, chunks, seed_range
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import Scenario, apply_overrides, parse_scenario, read_scenario_text, resolve
from ringtrack.world.scenario_schema import OutageSpec, ScenarioSpec

STRATEGIES = ("constant", "self")  # compared by default; the first is the baseline of the savings
MOVING_MODES = ("centralized", "decentralized")
OUTAGE_START = 100  # first step of a swept outage
SWEPT = ("drop", "outage_steps", "communication_range")
# Per-trial quantities summarised as mean and sd: (key, label, unit) in figure order.
METRICS = (
    ("ctime", "Ctime", "steps"),
    ("converged", "share converged", "fraction"),
    ("com_bar", "Com-bar", "polls per robot per step"),
    ("messages", "robot-to-robot messages", "messages"),
    ("bytes", "robot-to-robot bytes", "B"),
    ("energy_per_robot", "radio energy per robot", "J"),
)
MOVING_METRICS = (("cerr", "Cerr (true)", "deg"), ("terr", "Terr", "m"))


# ---------------------------------------------------------------------------- types
class Cell(msgspec.Struct, frozen=True):
    """One value of each swept quantity: the drop probability, the length (steps) of a partition
    outage from step ``OUTAGE_START``, and the communication range (metres; None: unlimited)."""

    drop: float
    outage_steps: int
    communication_range: float | None


class FaultVariant(msgspec.Struct, frozen=True, kw_only=True):
    """A cell (its index into the sweep's ``cells`` and its values, as :class:`Cell`) and a variant:
    the strategy and estimation mode."""

    cell: int
    drop: float
    outage_steps: int
    communication_range: float | None
    strategy: str
    estimation: str


class FaultTrial(FaultVariant, frozen=True, kw_only=True):
    """One trial of a cell and variant (see the module docstring for the steps its costs count):
    Ctime (steps; None: not converged), Com-bar (polls per robot per step; a moving target's over
    every step, None when a stationary one did not converge), robot-to-robot messages and payload
    bytes, radio energy (joules, the team's and per robot), the fault layer's counts, and for a
    moving target the mean true Cerr (degrees) and Terr (metres) from ``settle`` on (else unset)."""

    trial: int
    seed: int
    ctime: int | None
    converged: bool
    com_bar: float | None
    messages: int
    bytes: int
    energy_j: float
    energy_per_robot: float
    faults: dict[str, int]
    cerr: float | UnsetType = UNSET
    terr: float | UnsetType = UNSET


class FaultSummary(FaultVariant, frozen=True, kw_only=True):
    """Mean and sd over the ``trials`` of a cell and variant of each of :data:`METRICS` (and
    :data:`MOVING_METRICS` for a moving target, else unset), over the trials where it is known (None:
    in none); units as :class:`FaultTrial`'s, ``converged`` a fraction. ``steps_run``: steps the
    engine ran the batch."""

    trials: int
    steps_run: int
    ctime_mean: float | None
    ctime_sd: float | None
    converged_mean: float | None
    converged_sd: float | None
    com_bar_mean: float | None
    com_bar_sd: float | None
    messages_mean: float | None
    messages_sd: float | None
    bytes_mean: float | None
    bytes_sd: float | None
    energy_per_robot_mean: float | None
    energy_per_robot_sd: float | None
    cerr_mean: float | None | UnsetType = UNSET
    cerr_sd: float | None | UnsetType = UNSET
    terr_mean: float | None | UnsetType = UNSET
    terr_sd: float | None | UnsetType = UNSET

    def mean(self, metric: str) -> float | None:
        """The mean of the metric named ``metric`` (a key of :data:`METRICS` or :data:`MOVING_METRICS`)."""
        return _known(getattr(self, f"{metric}_mean"))

    def sd(self, metric: str) -> float | None:
        """The standard deviation of the metric named ``metric``."""
        return _known(getattr(self, f"{metric}_sd"))


def _known(value: float | None | UnsetType) -> float | None:
    return None if value is UNSET else value


class Saving(msgspec.Struct, frozen=True):
    """In one cell and estimation mode, the mean radio energy per robot ``strategy`` saves against
    the ``baseline`` (the sweep's first strategy): joules, and as a fraction of the baseline's."""

    cell: int
    estimation: str
    strategy: str
    baseline: str
    saved_per_robot_j: float
    saved_share: float


class VerifyCheck(FaultVariant, frozen=True, kw_only=True):
    """One run re-run as a lockstep team over Zenoh (``--verify``) for the ``steps`` the engine ran
    it: the team's exit code and, when it ran, the steps logged, the largest difference of an angle
    (radians; None: not as many steps as the engine's) and whether every trigger, the fault counts and
    each robot's radio energy equal the engine's; ``equal`` when all do."""

    trial: int
    seed: int
    steps: int
    exit_code: int
    steps_logged: int | UnsetType = UNSET
    max_angle_difference: float | None | UnsetType = UNSET
    triggers_equal: bool | UnsetType = UNSET
    faults_equal: bool | UnsetType = UNSET
    energy_equal: bool | UnsetType = UNSET
    equal: bool


class Verification(msgspec.Struct, frozen=True):
    """What ``--verify`` came to: the runs requested, the seconds the checks took, each check."""

    requested: int
    wall_s: float
    all_equal: bool
    runs: list[VerifyCheck]


class FaultStudy(msgspec.Struct, frozen=True, kw_only=True):
    """What ``experiment faults`` came to (its JSON): every cell and variant of the sweep on seeds
    ``seed .. seed + trials - 1`` with ``robots`` robots; ``swept`` names the quantities that take
    more than one value, ``labels`` names each strategy (in the order compared, the first the
    baseline of the savings), ``settle`` the step a moving target's means start from (None:
    stationary). ``summary`` has an entry per cell and variant, ``rows`` a trial each; ``verify``
    is set by ``--verify``. ``wall_s``: seconds the sweep took."""

    experiment: Literal["faults"] = "faults"
    scenario: str
    moving: bool
    robots: int
    seed: int
    trials: int
    settle: int | None
    outage_start: int
    swept: list[str]
    cells: list[Cell]
    labels: dict[str, str]
    wall_s: float
    summary: list[FaultSummary]
    savings: list[Saving]
    rows: list[FaultTrial]
    verify: Verification | UnsetType = UNSET

    @property
    def costs_span(self) -> str:
        """Which steps the costs count, as tables and figures say it (see the module docstring)."""
        return "costs over each whole run" if self.moving else "costs to Ctime"


def summary_columns(study: FaultStudy) -> list[str]:
    """The CSV columns of a sweep's summary: a moving target's metrics only for a moving target."""
    unused = () if study.moving else [f"{key}_{moment}" for key, _, _ in MOVING_METRICS for moment in ("mean", "sd")]
    return struct_columns(FaultSummary, leave_out=unused)


# ---------------------------------------------------------------------------- runs
def base_spec(base: str) -> tuple[ScenarioSpec, str]:
    """The base scenario with random starts (the trials' seeds place the robots)."""
    text, label = read_scenario_text(base)
    spec = parse_scenario(text, label)
    return msgspec.structs.replace(spec, team=msgspec.structs.replace(spec.team, angles_deg=None)), label


def cell_scenario(spec: ScenarioSpec, label: str, cell: Cell, strategy: str, mode: str | None,
                  steps: int | None, seed: int | None = None) -> Scenario:
    """The base scenario in one cell with one strategy and estimation mode (and ``seed``)."""
    robots = spec.team.robots
    faults = spec.faults
    if cell.outage_steps:
        cut = OutageSpec(links=[(robots // 2 - 1, robots // 2), (robots - 1, 0)], from_step=OUTAGE_START,
                         to_step=OUTAGE_START + cell.outage_steps - 1)
        faults = msgspec.structs.replace(faults, outages=[*faults.outages, cut])
    limits = msgspec.structs.replace(spec.limits, communication_range=cell.communication_range)
    spec = msgspec.structs.replace(spec, faults=faults, limits=limits)
    return resolve(apply_overrides(spec, drop=cell.drop, strategy=strategy, estimation=mode, max_steps=steps,
                                   seed=seed), label)


def variants(scenario: Scenario, strategies: Sequence[str] = STRATEGIES) -> list[tuple[str, str]]:
    """(strategy, estimation mode) pairs: every strategy, and for a moving target each mode."""
    modes = MOVING_MODES if scenario.moving else (scenario.estimation.mode,)
    return [(strategy, mode) for mode in modes for strategy in strategies]


def trial_rows(history: engine.History, settle: int, variant: FaultVariant, first: int) -> list[FaultTrial]:
    """Per trial of a cell and variant (the study's trial ``first`` onwards): Ctime, converged, Com-bar
    and the costs of the run (see the module docstring)."""
    scenario = history.scenario
    robots = scenario.robots
    ctime, com_bar = history.ctime, history.com_bar
    assert history.energy is not None and history.sent_bytes is not None
    head = msgspec.structs.asdict(variant)
    rows = []
    for trial in range(len(history.seeds)):
        converged = bool(ctime[trial] > 0)
        window = slice(None) if scenario.moving or not converged else slice(0, int(ctime[trial]))
        polls = history.triggers[window, trial] != 0
        rows.append(FaultTrial(
            **head,
            trial=first + trial,
            seed=history.seeds[trial],
            ctime=int(ctime[trial]) if converged else None,
            converged=converged,
            com_bar=float(polls.mean()) if scenario.moving else float(com_bar[trial]) if converged else None,
            messages=int(history.sent[window, trial].sum()),
            bytes=int(history.sent_bytes[window, trial].sum()),
            energy_j=float(history.energy[window, trial].sum()),
            energy_per_robot=float(history.energy[window, trial].sum()) / robots,
            faults=engine.fault_totals(history, trial, window),
            cerr=float(history.cerr_true[settle:, trial].mean()) if scenario.moving else UNSET,
            terr=float(history.terr[settle:, trial].mean()) if scenario.moving else UNSET,
        ))
    return rows


def summarise(rows: list[FaultTrial], keys: list[str]) -> dict[str, float | None]:
    """Mean and sd over the trials of each metric named in ``keys`` (over the trials where it is
    known), as the fields of :class:`FaultSummary`; the share converged as a fraction."""
    summary: dict[str, float | None] = {}
    for key in keys:
        values = np.array([value for row in rows if (value := getattr(row, key)) is not None], dtype=float)
        summary[f"{key}_mean"] = float(values.mean()) if len(values) else None
        summary[f"{key}_sd"] = float(values.std()) if len(values) else None
    return summary


@dataclass(frozen=True)
class FaultTask(Task):
    """A chunk of the trials of one variant in a group of cells that differ only in their faults
    (:func:`_batches`): each cell's :class:`FaultVariant` and scenario, and the step a moving
    target's means start from."""

    variants: list[FaultVariant]
    scenarios: list[Scenario]
    settle: int


class FaultPart(msgspec.Struct, frozen=True):
    """What a :class:`FaultTask` came to: a row per cell and trial, and the steps its batch ran."""

    rows: list[FaultTrial]
    steps_run: int


def fault_task(task: FaultTask) -> FaultPart:
    """Run a chunk of trials of every cell of the task as one engine batch, a fault plan per trial."""
    first, count = task.scenarios[0], len(task.seeds)
    batch = engine.run(first, task.seeds * len(task.scenarios), until_converged=not first.moving,
                       record_positions=False, plans=[scenario.faults for scenario in task.scenarios
                                                      for _ in task.seeds])
    rows = []
    for position, (variant, scenario) in enumerate(zip(task.variants, task.scenarios, strict=True)):
        history = batch.select(slice(position * count, (position + 1) * count), scenario)
        rows += trial_rows(history, task.settle, variant, task.first)
    return FaultPart(rows, batch.steps)


def faults_experiment(
    base: str,
    cells: list[Cell],
    trials: int,
    seed: int,
    steps: int | None = None,
    settle: int = 300,
    strategies: Sequence[str] = STRATEGIES,
    execution: Execution = IN_PROCESS,
) -> FaultStudy:
    """Run every cell and variant of the ``strategies`` (the first the baseline of the savings) in
    the engine, in tasks of ``execution.trials_per_task()`` trials (:mod:`tools.studies.runner`)."""
    spec, label = base_spec(base)
    seeds = list(range(seed, seed + trials))
    batch = execution.trials_per_task()
    probe = cell_scenario(spec, label, cells[0], strategies[0], None, steps)
    if probe.moving:
        check_settle(settle, probe.max_steps)
    keys = [key for key, _, _ in METRICS + (MOVING_METRICS if probe.moving else ())]
    started = time.perf_counter()
    tasks = []
    for group in _batches(cells):
        for strategy, mode in variants(probe, strategies):
            more = f" and {len(group) - 1} more cells" if len(group) > 1 else ""
            tasks += [FaultTask(f"{_run_label(cells[group[0]], strategy, mode)}{more} {seed_range(part)}", first,
                                part, [FaultVariant(cell=index, **msgspec.structs.asdict(cells[index]),
                                                    strategy=strategy, estimation=mode) for index in group],
                                [cell_scenario(spec, label, cells[index], strategy, mode, steps) for index in group],
                                settle)
                      for first, part in chunks(seeds, batch)]
    parameters = {"scenario": base, "cells": [msgspec.to_builtins(cell) for cell in cells], "trials": trials,
                  "seed": seed, "steps": steps, "settle": settle, "strategies": list(strategies)}
    parts = run_study(Study("faults", parameters, tasks, fault_task, FaultPart, batch), execution)
    rows: dict[FaultVariant, list[FaultTrial]] = {}
    steps_run: dict[FaultVariant, int] = {}
    for task, part in zip(tasks, parts, strict=True):
        for variant in task.variants:
            steps_run[variant] = max(steps_run.get(variant, 0), part.steps_run)
            rows.setdefault(variant, []).extend(row for row in part.rows if row.cell == variant.cell)
    summary = sorted((FaultSummary(**msgspec.structs.asdict(variant), trials=trials, steps_run=steps_run[variant],
                                   **summarise(trial, keys))  # type: ignore[arg-type]  # means, sds
                      for variant, trial in rows.items()),
                     key=lambda entry: (entry.cell, entry.estimation, entry.strategy))
    return FaultStudy(
        scenario=base,
        moving=probe.moving,
        robots=probe.robots,
        seed=seed,
        trials=trials,
        settle=settle if probe.moving else None,
        outage_start=OUTAGE_START,
        swept=[name for name in SWEPT if len({getattr(cell, name) for cell in cells}) > 1],
        cells=list(cells),
        labels=strategy_labels(strategies),
        wall_s=time.perf_counter() - started,
        summary=summary,
        savings=savings(summary, strategies[0]),
        rows=sorted((row for trial in rows.values() for row in trial),
                    key=lambda row: (row.cell, row.estimation, row.strategy, row.trial)),
    )


def _batches(cells: list[Cell]) -> list[list[int]]:
    """Indices of the cells that differ only in their faults (drop, outage), so that each group
    runs as one engine batch with a fault plan per trial; cells of another range run apart."""
    groups: dict[float | None, list[int]] = {}
    for index, cell in enumerate(cells):
        groups.setdefault(cell.communication_range, []).append(index)
    return list(groups.values())


def savings(summary: list[FaultSummary], baseline: str) -> list[Saving]:
    """Per cell, estimation mode and strategy other than the ``baseline``: the mean radio energy per
    robot it saves against the baseline (joules, and as a fraction of the baseline's)."""
    found = []
    by_key = {(entry.cell, entry.estimation, entry.strategy): entry for entry in summary}
    for (cell, mode, strategy), entry in by_key.items():
        reference = by_key.get((cell, mode, baseline))
        if strategy == baseline or reference is None or not reference.energy_per_robot_mean:
            continue
        assert entry.energy_per_robot_mean is not None  # every trial has an energy
        saved = reference.energy_per_robot_mean - entry.energy_per_robot_mean
        found.append(Saving(cell=cell, estimation=mode, strategy=strategy, baseline=baseline, saved_per_robot_j=saved,
                            saved_share=saved / reference.energy_per_robot_mean))
    return found


def _run_label(cell: Cell, strategy: str, mode: str) -> str:
    reach = "inf" if cell.communication_range is None else f"{cell.communication_range:g}"
    return f"drop {cell.drop:g} outage {cell.outage_steps} r_c {reach}: {strategy}+{mode}"


# ---------------------------------------------------------------------------- verification
def verify(base: str, cells: list[Cell], trials: int, count: int, seed: int, steps: int | None, runs: Path,
           strategies: Sequence[str] = STRATEGIES) -> list[VerifyCheck]:
    """Re-run ``count`` (cell, variant, trial) runs of a sweep on seeds ``seed ..`` (drawn by
    ``seed``) alone in the engine (a stationary target's until it converged) and as lockstep teams
    over Zenoh for as many steps; each team must equal its engine run: angles to 1e-9, every trigger,
    the fault counts, and each robot's radio energy to a relative 1e-9."""
    spec, label = base_spec(base)
    probe = cell_scenario(spec, label, cells[0], strategies[0], None, steps)
    keys = sorted((index, strategy, mode) for index in range(len(cells))
                  for strategy, mode in variants(probe, strategies))
    choices = [(key, trial) for key in keys for trial in range(trials)]
    picked = np.random.default_rng(seed).choice(len(choices), size=min(count, len(choices)), replace=False)
    checks = []
    for choice in sorted(int(index) for index in picked):
        (cell_index, strategy, mode), trial = choices[choice]
        trial_seed = seed + trial
        alone = cell_scenario(spec, label, cells[cell_index], strategy, mode, steps)
        history = engine.run(alone, [trial_seed], until_converged=not alone.moving, record_positions=False)
        scenario = cell_scenario(spec, label, cells[cell_index], strategy, mode, history.steps, trial_seed)
        result = spawn_team(TeamPlan(scenario=scenario, clock="lockstep", runs=runs, dashboard=False, quiet=True))
        run = {"cell": cell_index, **msgspec.structs.asdict(cells[cell_index]), "strategy": strategy,
               "estimation": mode, "trial": trial, "seed": trial_seed, "steps": history.steps,
               "exit_code": result.exit_code}
        if result.exit_code == 0 and result.energy is not None:
            logged = history_from_log(read_log(Path(result.log)))
            engine_faults = engine.fault_totals(history, 0)
            energy = history.energy[:, 0].sum(axis=0)  # type: ignore[index]
            wire_energy = np.array([result.energy.transmit_j, result.energy.receive_j]).T
            same_steps = logged.steps == history.steps
            difference = float(np.max(np.abs(logged.angles[:, 0] - history.angles[:, 0]))) if same_steps else None
            triggers_equal = same_steps and bool(np.array_equal(logged.triggers[:, 0], history.triggers[:, 0]))
            faults_equal = all(result.faults.get(name) == engine_faults[name] for name in engine.FAULT_COLUMNS)
            energy_equal = bool(np.allclose(wire_energy, energy, rtol=1e-9, atol=0.0))
            checks.append(VerifyCheck(
                **run, steps_logged=logged.steps, max_angle_difference=difference, triggers_equal=triggers_equal,
                faults_equal=faults_equal, energy_equal=energy_equal,
                equal=bool(difference is not None and difference < 1e-9 and triggers_equal and faults_equal
                           and energy_equal)))
        else:
            checks.append(VerifyCheck(**run, equal=False))
    return checks
