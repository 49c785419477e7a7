"""``ringtrack experiment stationary``: the paper's comparison of the constant and self-triggered
strategies (or any of constant, self, plan: ``--strategies``) on the same seeded random starts, over
one or several team sizes."""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import msgspec
import numpy as np

from ringtrack.agents import engine
from ringtrack.agents.strategy import StrategyError, check_strategy, strategy_for
from ringtrack.tools.output.console import UsageError
from ringtrack.tools.output.files import struct_columns
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import IN_PROCESS, Execution, Study, Task, chunks, seed_range
from ringtrack.world.geometry import FloatArray
from ringtrack.world.metrics import communication_rate, convergence_step, settled_mean
from ringtrack.world.scenario import Scenario, apply_overrides, parse_scenario, read_scenario_text, resolve
from ringtrack.world.scenario_errors import ScenarioError
from ringtrack.world.target import Circle

STRATEGIES = ("constant", "self")  # compared by default; the first is the baseline of the ratios


class StationaryTrial(msgspec.Struct, frozen=True):
    """One trial of one strategy and team size (a row of ``experiment stationary --csv``).

    ``ctime`` is the trial's Ctime (steps; None: not converged within the steps run), ``ctime_true``
    the same by the true Cerr within the steps the trial ran alone, up to its Ctime (None: not
    reached by then), ``com_bar`` polls per robot per step up to Ctime (None unless
    converged); ``triggers`` counts the polls of steps 1..Ctime (Com-bar's numerator) and
    ``robot_bytes`` the robot-to-robot payload bytes of those steps."""

    robots: int
    strategy: str
    trial: int
    seed: int
    converged: bool
    ctime: int | None
    ctime_true: int | None
    com_bar: float | None
    triggers: int
    robot_bytes: int


class StationaryCell(msgspec.Struct, frozen=True):
    """One strategy at one team size over the trials: how many converged, the mean and standard
    deviation of Ctime (steps) and Com-bar (polls per robot per step) over those that did (None when
    none did), the mean robot-to-robot bytes of a trial, and the settings: trigger tolerance
    ``sigma_deg`` and convergence threshold ``threshold_deg`` (degrees) and the control law."""

    robots: int
    strategy: str
    trials: int
    converged: int
    ctime_mean: float | None
    ctime_std: float | None
    com_bar_mean: float | None
    com_bar_std: float | None
    robot_bytes_mean: float
    sigma_deg: float
    law: str
    threshold_deg: float


class Ratio(msgspec.Struct, frozen=True):
    """A strategy's means to the baseline's (the study's first strategy) at one team size."""

    robots: int
    strategy: str
    baseline: str
    ctime_ratio: float
    com_bar_ratio: float


class StationaryStudy(msgspec.Struct, frozen=True, kw_only=True):
    """What ``experiment stationary`` came to (its JSON): the strategies (as given: names or files)
    on seeds ``seed .. seed + trials - 1`` for every team size in ``robots``; ``labels`` names each
    strategy (by its reported name, in the order compared) for tables and figures. ``summary`` has a
    cell per team size and strategy, ``ratios`` one per team size and strategy after the first,
    ``rows`` a trial each. ``wall_s``: seconds the study took."""

    experiment: Literal["stationary"] = "stationary"
    scenario: str
    seed: int
    trials: int
    robots: list[int]
    strategies: list[str]
    labels: dict[str, str]
    wall_s: float
    summary: list[StationaryCell]
    ratios: list[Ratio]
    rows: list[StationaryTrial]


# The stationary CSV's columns (``experiment stationary --csv``): a trial's fields but its bytes.
STATIONARY_COLUMNS = struct_columns(StationaryTrial, leave_out=("robot_bytes",))


class MovingFigures(msgspec.Struct, frozen=True, kw_only=True):
    """The figures of a moving-target run over some of its trials (:func:`moving_figures`): true
    Cerr (degrees) and Terr (metres) means once the first ``settle`` steps are left out (None: no
    step left); over the whole run the poll rate (polls per robot per step), the polls and the
    robot-to-robot messages (pushes included) and payload bytes (totals of a trial, averaged over the
    trials; and per step), the robot-to-robot messages per robot-step after ``settle``, and the
    estimation messages per step (centralized: every robot's range and the centre's estimate).
    Keyword-only: a record that adds its own fields lists them first."""

    cerr_mean_deg: float | None
    terr_mean: float | None
    poll_rate: float
    polls: float
    robot_messages: float
    robot_bytes: float
    robot_messages_per_step: float
    robot_messages_per_robot_step: float
    robot_bytes_per_step: float
    estimation_messages_per_step: int


class MovingSetting(MovingFigures, frozen=True):
    """A moving-target run where it stands, with its figures: its ``group`` ("comparison": the base
    scenario's circle, "velocities": one of the paper's velocity settings), the target's ``speed``
    (m/s), ``angular_speed`` (rad/s) and circle ``radius`` (metres), the strategy, estimation mode
    and (decentralized) fusion rule."""

    group: str
    speed: float
    angular_speed: float
    radius: float
    strategy: str
    estimation: str
    fusion: str | None


class MovingTrial(MovingSetting, frozen=True):
    """One trial of a distinct moving-target run (a row of ``experiment moving --csv``), its figures
    over this trial alone."""

    trial: int
    seed: int


class MovingRun(MovingSetting, frozen=True, kw_only=True):
    """One run of the moving-target study on the ``scenario`` (its name), its figures over every
    trial, ``terr_ratio`` its Terr over that of the study's centralized reference at the same target
    velocity (:func:`centralized_ratios`; None without one; as ``experiment tracking``'s), and the trial-mean true Cerr
    (degrees) and Terr (metres) every ``series_stride`` steps."""

    scenario: str
    terr_ratio: float | None
    cerr_series_deg: list[float]
    terr_series: list[float]


class MovingStudy(msgspec.Struct, frozen=True, kw_only=True):
    """What ``experiment moving`` came to (its JSON): ``runs`` of ``steps`` steps of ``dt`` seconds on
    seeds ``seed .. seed + trials - 1``, means from step ``settle`` on; ``rows`` a trial of every
    distinct run; ``labels`` names each strategy (by its reported name, in the order compared).
    ``wall_s``: seconds the study took."""

    experiment: Literal["moving"] = "moving"
    scenario: str
    trials: int
    seed: int
    steps: int
    dt: float
    settle: int
    series_stride: int
    labels: dict[str, str]
    wall_s: float
    runs: list[MovingRun]
    rows: list[MovingTrial]


# One row per trial of every distinct moving-target run (``experiment moving --csv``).
MOVING_COLUMNS = struct_columns(MovingTrial)


def random_start_scenarios(base: str, robots: int, strategies: Sequence[str] = STRATEGIES,
                           **overrides: object) -> dict[str, Scenario]:
    """The base scenario with ``robots`` robots, random starts and default threshold, per strategy
    (keyed by the strategy's name)."""
    text, label = read_scenario_text(base)
    spec = parse_scenario(text, label)
    spec = msgspec.structs.replace(spec, team=msgspec.structs.replace(spec.team, angles_deg=None))
    scenarios = {}
    for strategy in strategies:
        scenario = resolve(apply_overrides(spec, robots=robots, strategy=strategy, **overrides), label)
        needed = strategy_for(strategy).estimation
        if needed not in (None, scenario.estimation.mode):
            raise UsageError(f"--strategies: the {strategy_name(strategy)} strategy needs estimation.mode = "
                             f"'{needed}' and {base} has '{scenario.estimation.mode}'; give a scenario with "
                             f"estimation.mode = '{needed}', or compare it with experiment moving or tracking")
        try:
            check_strategy(scenario)
        except StrategyError as error:
            raise UsageError(f"--strategies: {error}") from None
        scenarios[strategy_name(strategy)] = scenario
    return scenarios


# Trials of a stationary study's task unless --batch says otherwise: the more robots a batch steps at
# once, the less its cost per step that does not grow with them weighs (about a third of a millisecond).
STATIONARY_BATCH = 420


@dataclass(frozen=True)
class StationaryTask(Task):
    """A chunk of the runs of one strategy, its team sizes mixed (its reported name): its run ``i``
    runs ``scenarios[i]`` (its team size's) from ``seeds[i]`` and is trial ``trials[i]`` of its
    team size; ``first`` indexes its first run in its strategy's list of (team size, trial) runs."""

    strategy: str
    scenarios: list[Scenario]
    trials: list[int]

    def cost(self) -> float:
        """The robots of its trials, which a batch's steps cost roughly in proportion to."""
        return sum(scenario.robots for scenario in self.scenarios)


class StationaryPart(msgspec.Struct, frozen=True):
    """What a :class:`StationaryTask` came to: a row per trial."""

    rows: list[StationaryTrial]


def stationary_task(task: StationaryTask) -> StationaryPart:
    """Run a chunk of trials until each converged, as one batch (teams of one size together:
    :func:`agents.engine.run_until_converged`): a :class:`StationaryTrial` each, in the chunk's order."""
    order = sorted(range(len(task.seeds)), key=lambda index: task.scenarios[index].robots)
    series = engine.run_until_converged([task.scenarios[index] for index in order],
                                        [task.seeds[index] for index in order])
    rows: dict[int, StationaryTrial] = {}
    for column, index in enumerate(order):
        scenario, ctime = task.scenarios[index], int(series.ctime[column])
        steps = slice(None, ctime or None)  # a trial alone stops at its own Ctime
        polls = int(series.polls[steps, column].sum())
        rows[index] = StationaryTrial(
            robots=scenario.robots,
            strategy=task.strategy,
            trial=task.trials[index],
            seed=task.seeds[index],
            converged=ctime > 0,
            ctime=ctime or None,
            ctime_true=int(convergence_step(series.cerr_true[steps, column], np.rad2deg(scenario.threshold))) or None,
            com_bar=float(communication_rate(polls, scenario.robots, ctime)) if ctime else None,
            triggers=polls,
            robot_bytes=int(series.sent_bytes[steps, column].sum()),
        )
    return StationaryPart([rows[index] for index in range(len(order))])


def stationary_cell(rows: list[StationaryTrial], scenario: Scenario) -> StationaryCell:
    """The :class:`StationaryCell` of one strategy and team size from its trials' rows."""
    done = [row for row in rows if row.converged]
    ctime = np.array([row.ctime for row in done], dtype=float)
    com_bar = np.array([row.com_bar for row in done], dtype=float)
    return StationaryCell(
        robots=rows[0].robots,
        strategy=rows[0].strategy,
        trials=len(rows),
        converged=len(done),
        ctime_mean=float(ctime.mean()) if done else None,
        ctime_std=float(ctime.std()) if done else None,
        com_bar_mean=float(com_bar.mean()) if done else None,
        com_bar_std=float(com_bar.std()) if done else None,
        robot_bytes_mean=float(np.mean([row.robot_bytes for row in rows])),
        sigma_deg=float(np.rad2deg(scenario.control.sigma)),
        law=scenario.control.law,
        threshold_deg=float(np.rad2deg(scenario.threshold)),
    )


def stationary_experiment(
    base: str,
    robots: Sequence[int],
    trials: int,
    seed: int,
    strategies: Sequence[str] = STRATEGIES,
    execution: Execution = IN_PROCESS,
    **overrides: object,
) -> StationaryStudy:
    """Run the ``strategies`` (default constant and self) for every team size on seeds ``seed ..
    seed + trials - 1``, in tasks of ``execution.trials_per_task(STATIONARY_BATCH)`` trials
    (:mod:`tools.studies.runner`).

    Returns the study: a :class:`StationaryTrial` per trial, a :class:`StationaryCell` per team size
    and strategy (mean and standard deviation of Ctime and Com-bar), and per team size and strategy
    after the first the :class:`Ratio` of its means to the first's (the baseline; by default
    self / constant).
    """
    if trials < 1:
        raise UsageError(f"--trials {trials}: give at least 1 trial")
    started = time.perf_counter()
    scenarios = {size: random_start_scenarios(base, size, strategies, **overrides) for size in robots}
    # a strategy's runs, team sizes mixed in each chunk (so that chunks cost alike): (size, trial)
    mixed = [(size, trial) for trial in range(trials) for size in robots]
    batch = execution.trials_per_task(STATIONARY_BATCH)
    tasks = [StationaryTask(f"{strategy} runs {first}-{first + len(part) - 1} of {len(mixed)}", first,
                            [seed + trial for _, trial in part], strategy,
                            [scenarios[size][strategy] for size, _ in part], [trial for _, trial in part])
             for strategy in scenarios[robots[0]] for first, part in chunks(mixed, batch)]
    parameters = {"scenario": base, "robots": list(robots), "trials": trials, "seed": seed,
                  "strategies": list(strategies), **overrides}
    parts = run_study(Study("stationary", parameters, tasks, stationary_task, StationaryPart, batch), execution)
    by_cell: dict[tuple[int, str], list[StationaryTrial]] = {(size, strategy): [] for size in robots
                                                             for strategy in scenarios[size]}
    for row in sorted((row for part in parts for row in part.rows), key=lambda row: row.trial):
        by_cell[row.robots, row.strategy].append(row)
    summary = [stationary_cell(rows, scenarios[size][strategy]) for (size, strategy), rows in by_cell.items()]
    return StationaryStudy(
        scenario=base,
        seed=seed,
        trials=trials,
        robots=list(robots),
        strategies=list(strategies),
        labels=strategy_labels(strategies),
        wall_s=time.perf_counter() - started,
        summary=summary,
        ratios=[ratio for size in robots for ratio in size_ratios([cell for cell in summary if cell.robots == size])],
        rows=[row for rows in by_cell.values() for row in rows],
    )


def size_ratios(cells: list[StationaryCell]) -> list[Ratio]:
    """At one team size, each strategy's means to the first's (the baseline), where both converged."""
    baseline, *others = cells
    ratios = []
    for compared in others:
        if baseline.ctime_mean and compared.ctime_mean:
            assert baseline.com_bar_mean is not None and compared.com_bar_mean is not None  # known when converged
            ratios.append(Ratio(robots=compared.robots, strategy=compared.strategy, baseline=baseline.strategy,
                                ctime_ratio=compared.ctime_mean / baseline.ctime_mean,
                                com_bar_ratio=compared.com_bar_mean / baseline.com_bar_mean))
    return ratios


def strategy_labels(strategies: Sequence[str]) -> dict[str, str]:
    """How tables and figures name each strategy (a registered name or a file's path), by the name
    it is reported by, in the order given: the strategy's own :meth:`Strategy.display_label`."""
    return {strategy_name(strategy): strategy_for(strategy).display_label() for strategy in strategies}


# ---------------------------------------------------------------------------- moving target
VELOCITY_SETTINGS = ((0.6, 0.6), (1.0, 0.6), (1.0, 0.4), (1.0, 0.8))
MAIN_STRATEGIES = (("constant", "centralized"), ("self", "centralized"), ("self", "decentralized"))
VELOCITY_STRATEGIES = (("constant", "centralized"), ("self", "decentralized"))
SERIES_STRIDE = 5  # steps between the points of the Cerr/Terr series written to JSON


def circle_of(base: str) -> tuple[float, float]:
    """``(speed, angular_speed)`` of the base scenario's circling target."""
    text, label = read_scenario_text(base)
    target = parse_scenario(text, label).target
    if not isinstance(target, Circle):
        raise UsageError(f"{label}: experiment moving needs target.motion = 'circle'")
    return target.speed, target.angular_speed


def moving_scenario(base: str, strategy: str, mode: str, speed: float, angular_speed: float,
                    steps: int | None, fusion: str | None = None) -> Scenario:
    """The base scenario's circling target at ``speed`` (m/s) and ``angular_speed`` (rad/s), with the
    given communication strategy, estimation mode and (decentralized) fusion rule."""
    text, label = read_scenario_text(base)
    spec = parse_scenario(text, label)
    circle_of(base)
    target = msgspec.structs.replace(spec.target, speed=speed, angular_speed=angular_speed)
    estimation = msgspec.structs.replace(spec.estimation, fusion=fusion or spec.estimation.fusion)
    spec = msgspec.structs.replace(spec, target=target, estimation=estimation)
    return resolve(apply_overrides(spec, strategy=strategy, estimation=mode, max_steps=steps), label)


FIXED_POINT = 2.0**32  # units per degree or metre of the float sums of StepTotals


class StepTotals(msgspec.Struct, frozen=True):
    """Per-step sums over some ``trials`` of a moving-target run (what a task hands on, and what a
    run's figures and series are computed from): true Cerr (degrees) and Terr (metres), robots that
    polled, robot-to-robot messages (pushes included) and their payload bytes. Cerr and Terr are
    summed in fixed point (integers of ``1 / FIXED_POINT`` degrees or metres, each trial's value
    rounded once), so sums add exactly: a run's figures do not depend on how its trials were cut
    into batches or which worker ran them."""

    trials: int
    cerr_deg: list[int]
    terr: list[int]
    polls: list[int]
    messages: list[int]
    payload: list[int]

    def mean(self, name: str) -> FloatArray:
        """The trial-mean series of the quantity ``name`` (one of the sums), per step (degrees or
        metres for Cerr and Terr)."""
        scale = FIXED_POINT if name in ("cerr_deg", "terr") else 1.0
        return np.array(getattr(self, name), dtype=float) / (scale * self.trials)


def fixed_point_sums(values: FloatArray) -> list[int]:
    """Per-step sums (steps on axis 0, trials on axis 1) of ``values`` in fixed point (see
    :class:`StepTotals`); exact whatever the order of the trials."""
    return np.rint(values * FIXED_POINT).astype(np.int64).sum(axis=1).tolist()


def step_totals(history: engine.History, trials: slice) -> StepTotals:
    """The :class:`StepTotals` of the ``trials`` of a batch (a slice of its trial axis)."""
    assert history.sent_bytes is not None  # engine runs count bytes
    return StepTotals(
        trials=len(history.seeds[trials]),
        cerr_deg=fixed_point_sums(history.cerr_true[:, trials]),
        terr=fixed_point_sums(history.terr[:, trials]),
        polls=(history.triggers[:, trials] != 0).sum(axis=(1, 2)).tolist(),
        messages=history.sent[:, trials].sum(axis=(1, 2)).tolist(),
        payload=history.sent_bytes[:, trials].sum(axis=(1, 2)).tolist(),
    )


def combined(parts: Sequence[StepTotals]) -> StepTotals:
    """The totals over the trials of all ``parts`` (exact sums, step by step)."""
    sums = {name: exact_sum([getattr(part, name) for part in parts])
            for name in ("cerr_deg", "terr", "polls", "messages", "payload")}
    return StepTotals(trials=sum(part.trials for part in parts), **sums)


def exact_sum(series: Sequence[list[int]]) -> list[int]:
    """The step-by-step sum of integer per-step ``series`` (fixed point: :func:`fixed_point_sums`)."""
    return functools.reduce(np.add, (np.asarray(values, dtype=np.int64) for values in series)).tolist()


def check_settle(settle: int, steps: int, run: str = "a run") -> None:
    """Raise a :class:`UsageError` unless ``--settle`` leaves some of the ``steps`` of ``run`` to
    average: means are taken from step ``settle + 1`` on (1-based)."""
    if settle >= steps:
        raise UsageError(f"--settle {settle}: must be below the {steps} steps of {run}")


def moving_figures(totals: StepTotals, robots: int, settle: int, mode: str) -> MovingFigures:
    """The figures of a moving-target run of ``robots`` robots over the trials ``totals`` sums, means
    from step ``settle`` on (:func:`world.metrics.settled_mean` of the trial-mean series): see
    :class:`MovingFigures`."""
    steps, trials = len(totals.polls), totals.trials
    polls, messages, payload = (int(np.sum(getattr(totals, name))) for name in ("polls", "messages", "payload"))
    return MovingFigures(
        cerr_mean_deg=settled_mean(totals.mean("cerr_deg"), settle),
        terr_mean=settled_mean(totals.mean("terr"), settle),
        poll_rate=polls / (steps * trials * robots),
        polls=polls / trials,
        robot_messages=messages / trials,
        robot_bytes=payload / trials,
        robot_messages_per_step=messages / (steps * trials),
        robot_messages_per_robot_step=(settled_mean(totals.mean("messages"), settle) or 0.0) / robots,
        robot_bytes_per_step=payload / (steps * trials),
        estimation_messages_per_step=robots + 1 if mode == "centralized" else 0,
    )


@dataclass(frozen=True)
class MovingTask(Task):
    """A chunk of the trials of one distinct moving-target run: its scenario, where it stands (the
    fields of :class:`MovingSetting`) and the step its means start from."""

    scenario: Scenario
    setting: dict[str, Any]
    settle: int


class MovingPart(msgspec.Struct, frozen=True):
    """What a :class:`MovingTask` came to: a row per trial and the chunk's :class:`StepTotals`."""

    rows: list[MovingTrial]
    totals: StepTotals


def moving_task(task: MovingTask) -> MovingPart:
    """Run a chunk of trials of a moving-target run as one batch."""
    history = engine.run(task.scenario, task.seeds, record_positions=False)
    robots, mode = task.scenario.robots, task.setting["estimation"]
    rows = [MovingTrial(**task.setting, trial=task.first + index, seed=trial_seed,
                        **msgspec.structs.asdict(moving_figures(step_totals(history, slice(index, index + 1)), robots,
                                                                task.settle, mode)))
            for index, trial_seed in enumerate(task.seeds)]
    return MovingPart(rows, step_totals(history, slice(None)))


def moving_experiment(
    base: str,
    trials: int,
    seed: int,
    steps: int | None = None,
    settle: int = 300,
    velocities: bool = True,
    fusion: str | None = None,
    strategies: Sequence[str] | None = None,
    execution: Execution = IN_PROCESS,
) -> MovingStudy:
    """Run the comparison at the base scenario's circle and (``velocities``) the paper's velocity
    settings, in tasks of ``execution.trials_per_task()`` trials (:mod:`tools.studies.runner`); returns the
    study with, per run (:class:`MovingRun`), means from step ``settle`` on and the trial-mean Cerr
    (true, degrees) and Terr (metres) series, and per-trial rows (:class:`MovingTrial`) of every
    distinct run (the velocity setting equal to the scenario's circle repeats the comparison's runs:
    their trials are rows of group "comparison" only). ``strategies`` replaces the paper's runs by
    each strategy with a centralized and a decentralized EKF (:func:`moving_variants`)."""
    if trials < 1:
        raise UsageError(f"--trials {trials}: give at least 1 trial")
    started = time.perf_counter()
    main = circle_of(base)
    compared = MAIN_STRATEGIES if strategies is None else moving_variants(strategies)
    plan = [("comparison", main, strategy) for strategy in compared]
    if velocities:
        plan += [("velocities", setting, strategy) for setting in VELOCITY_SETTINGS
                 for strategy in (VELOCITY_STRATEGIES if strategies is None else compared)]
    seeds = list(range(seed, seed + trials))
    batch = execution.trials_per_task()
    runs: list[tuple[dict[str, Any], tuple]] = []  # (MovingSetting's own fields, the run's key)
    tasks: list[MovingTask] = []
    owners: list[tuple] = []  # the key of each task's run
    for group, (speed, angular_speed), (strategy, mode) in plan:
        key = (speed, angular_speed, strategy, mode)
        try:
            scenario = moving_scenario(base, strategy, mode, speed, angular_speed, steps, fusion)
        except ScenarioError:
            if group != "velocities":
                raise
            raise UsageError(f"the velocity setting v = {speed:g} m/s, w = {angular_speed:g} rad/s puts the target "
                             f"of {base} on a circle of radius {speed / angular_speed:g} m that leaves the region; "
                             "give --no-velocities to run the scenario's own circle only") from None
        check_settle(settle, scenario.max_steps)
        setting: dict[str, Any] = {  # MovingSetting's own fields
            "group": group, "speed": speed, "angular_speed": angular_speed, "radius": speed / angular_speed,
            "strategy": strategy_name(strategy), "estimation": mode,
            "fusion": scenario.estimation.fusion if mode == "decentralized" else None}
        if key not in owners:  # a velocity setting equal to the scenario's circle repeats two runs
            chunked = [MovingTask(f"v={speed} w={angular_speed} {strategy}+{mode} {seed_range(part)}", first, part,
                                  scenario, setting, settle)
                       for first, part in chunks(seeds, batch)]
            tasks += chunked
            owners += [key] * len(chunked)
        runs.append((setting, key))
    parameters = {"scenario": base, "trials": trials, "seed": seed, "steps": steps, "settle": settle,
                  "velocities": velocities, "fusion": fusion, "strategies": strategies}
    parts = run_study(Study("moving", parameters, tasks, moving_task, MovingPart, batch), execution)
    by_run: dict[tuple, list[StepTotals]] = {}
    for key, part in zip(owners, parts, strict=True):
        by_run.setdefault(key, []).append(part.totals)
    any_scenario = tasks[0].scenario
    return MovingStudy(
        scenario=base,
        trials=trials,
        seed=seed,
        steps=any_scenario.max_steps,
        dt=any_scenario.control.dt,
        settle=settle,
        series_stride=SERIES_STRIDE,
        labels=strategy_labels([strategy for strategy, _ in compared]),
        wall_s=time.perf_counter() - started,
        runs=centralized_ratios([moving_run(any_scenario.name, setting, combined(by_run[key]), any_scenario.robots,
                                            settle) for setting, key in runs],
                                strategy_name(reference_strategy(resolve(parse_scenario(*read_scenario_text(base)))))),
        rows=[row for part in parts for row in part.rows],
    )


def moving_run(scenario: str, setting: dict[str, Any], totals: StepTotals, robots: int, settle: int) -> MovingRun:
    """A run of the moving-target study on ``scenario`` from its setting and its trials' totals (its
    ``terr_ratio`` set by :func:`centralized_ratios`)."""
    return MovingRun(
        **setting,
        **msgspec.structs.asdict(moving_figures(totals, robots, settle, setting["estimation"])),
        scenario=scenario,
        terr_ratio=None,
        cerr_series_deg=totals.mean("cerr_deg")[::SERIES_STRIDE].tolist(),
        terr_series=totals.mean("terr")[::SERIES_STRIDE].tolist(),
    )


REFERENCE = "self"  # the centralized reference's strategy where the scenario's own needs decentralized estimation


def reference_strategy(scenario: Scenario) -> str:
    """The centralized reference's strategy: the scenario's own, or ``self`` where that needs
    decentralized estimation."""
    own = scenario.strategy.name
    return own if strategy_for(own).estimation in (None, "centralized") else REFERENCE


def centralized_ratios(runs: list[MovingRun], reference: str) -> list[MovingRun]:
    """The runs with ``terr_ratio``: Terr over that of the centralized run of strategy ``reference``
    (else the first centralized run) at the same target velocity."""
    centrals: dict[tuple[float, float], float | None] = {}
    for run in sorted(runs, key=lambda run: run.strategy != reference):  # the reference's first
        if run.estimation == "centralized":
            centrals.setdefault((run.speed, run.angular_speed), run.terr_mean)
    ratios = []
    for run in runs:
        central = centrals.get((run.speed, run.angular_speed))
        ratio = None if run.terr_mean is None or not central else run.terr_mean / central
        ratios.append(msgspec.structs.replace(run, terr_ratio=ratio))
    return ratios


def moving_variants(strategies: Sequence[str]) -> list[tuple[str, str]]:
    """``(strategy, estimation mode)`` runs of a moving-target comparison: each strategy with a
    centralized and a decentralized EKF, or only with the mode it needs."""
    variants = []
    for strategy in strategies:
        needed = strategy_for(strategy).estimation
        modes = [mode for mode in ("centralized", "decentralized") if needed in (None, mode)]
        if not modes:
            raise UsageError(f"--strategies: the {strategy_name(strategy)} strategy needs estimation.mode = "
                             f"'{needed}', and a moving target's runs estimate it (centralized or decentralized); "
                             "leave it out")
        variants += [(strategy, mode) for mode in modes]
    return variants


def run_label(strategy: str, mode: str) -> str:
    """``self, central``: a run's strategy and estimation, as the table names it."""
    return f"{strategy}, {mode.removesuffix('ized')}"


def strategy_name(value: str) -> str:
    """The name a strategy (a registered name or a file's path) is reported by."""
    return strategy_for(value).name
