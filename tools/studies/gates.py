"""``ringtrack experiment gates``: the belief strategy's trade-off between talk and tracking over its
push gate g, against the centralized self-triggered team on the same random starts."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import matplotlib.pyplot as plt
import msgspec

from ringtrack.agents import engine
from ringtrack.tools.output.console import UsageError
from ringtrack.tools.studies.experiment import StepTotals, check_settle, combined, step_totals, strategy_labels
from ringtrack.tools.studies.figures import drawn
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import IN_PROCESS, Execution, Study, Task, chunks, seed_range
from ringtrack.world.metrics import settled_mean
from ringtrack.world.scenario import Scenario, apply_overrides, load_scenario, resolve

GATED = "belief"  # the strategy whose push gate the study sweeps (decentralized)
GATE_PARAMETER = "push_gate"
REFERENCE = ("self", "centralized")  # what it is compared with: strategy and estimation mode


class GateFigures(msgspec.Struct, frozen=True):
    """Settled means of a run (:func:`world.metrics.settled_mean`; None: no step left): Terr
    (metres), true Cerr (degrees) and robot-to-robot messages per robot-step."""

    terr_mean: float | None
    cerr_mean_deg: float | None
    robot_messages_per_robot_step: float | None


class GatePoint(msgspec.Struct, frozen=True):
    """The gated strategy at push gate ``gate`` (dimensionless): its :class:`GateFigures`."""

    gate: float
    terr_mean: float | None
    cerr_mean_deg: float | None
    robot_messages_per_robot_step: float | None


class GatesStudy(msgspec.Struct, frozen=True, kw_only=True):
    """What ``experiment gates`` came to (its JSON): the reference run (``centralized``: the
    self-triggered strategy with a centralized EKF) and a point per gate, ``trials`` random starts
    each, means from step ``settle`` on; ``labels`` names the strategies. ``wall_s``: seconds the
    study took."""

    experiment: Literal["gates"] = "gates"
    scenario: str
    trials: int
    settle: int
    labels: dict[str, str]
    centralized: GateFigures
    points: list[GatePoint]
    wall_s: float


def with_gate(scenario: Scenario, gate: float) -> Scenario:
    return resolve(apply_overrides(scenario.spec, strategy_parameters={GATED: {GATE_PARAMETER: gate}}), scenario.name)


@dataclass(frozen=True)
class GatesTask(Task):
    """A chunk of the trials of the reference run or of one gate's run."""

    scenario: Scenario


def gates_task(task: GatesTask) -> StepTotals:
    """Run a chunk of trials as one batch: their :class:`StepTotals`."""
    return step_totals(engine.run(task.scenario, task.seeds, record_positions=False), slice(None))


def point(totals: StepTotals, robots: int, settle: int) -> GateFigures:
    """Terr (metres), Cerr (degrees, true) and robot-to-robot messages per robot-step of ``robots``
    robots, settled means of the trial-mean series."""
    messages = settled_mean(totals.mean("messages"), settle)
    return GateFigures(terr_mean=settled_mean(totals.mean("terr"), settle),
                       cerr_mean_deg=settled_mean(totals.mean("cerr_deg"), settle),
                       robot_messages_per_robot_step=None if messages is None else messages / robots)


def gates_experiment(base: str, gates: list[float], trials: int, settle: int, steps: int | None = None,
                     execution: Execution = IN_PROCESS) -> GatesStudy:
    """The reference run and the gated strategy at every gate on seeds ``0 .. trials - 1`` for
    ``steps`` steps (default the scenario's), in tasks of ``execution.trials_per_task()`` trials
    (:mod:`tools.studies.runner`), means from step ``settle`` on."""
    started = time.perf_counter()
    reference, mode = REFERENCE
    gated = load_scenario(base, strategy=GATED, estimation="decentralized", max_steps=steps)
    if not gated.moving:
        raise UsageError(f"{base}: experiment gates needs a moving target (target.motion = 'circle', 'random_walk' "
                         "or 'waypoints'); give a moving scenario such as authors-moving")
    runs = [(reference, load_scenario(base, strategy=reference, estimation=mode, max_steps=steps))]
    check_settle(settle, gated.max_steps)
    runs += [(f"{GATED} g={gate:g} (gate {number})", with_gate(gated, gate)) for number, gate in enumerate(gates)]
    batch = execution.trials_per_task()
    parts = chunks(list(range(trials)), batch)
    tasks = [GatesTask(f"{name} {seed_range(seeds)}", first, seeds, scenario)
             for name, scenario in runs for first, seeds in parts]
    parameters = {"scenario": base, "gates": gates, "trials": trials, "steps": steps, "settle": settle}
    totals = run_study(Study("gates", parameters, tasks, gates_task, StepTotals, batch), execution)
    robots = runs[0][1].robots
    central, *points = [point(combined(totals[index:index + len(parts)]), robots, settle)
                        for index in range(0, len(tasks), len(parts))]
    return GatesStudy(scenario=base, trials=trials, settle=settle, labels=strategy_labels([reference, GATED]),
                      centralized=central,
                      points=[GatePoint(gate, **msgspec.structs.asdict(entry))
                              for gate, entry in zip(gates, points, strict=True)],
                      wall_s=time.perf_counter() - started)


def plot_gates(result: GatesStudy, path: Path) -> None:
    figure, axis = plt.subplots(figsize=(6, 4.2), layout="constrained")
    points = result.points
    xs = [drawn(entry.robot_messages_per_robot_step) for entry in points]
    ys = [drawn(entry.terr_mean) for entry in points]
    axis.plot(xs, ys, "o-", color="tab:red", label=f"{result.labels[GATED]} (decentralized)")
    for entry, x, y in zip(points, xs, ys, strict=True):
        axis.annotate(f"g = {entry.gate:g}", (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    reference, mode = REFERENCE
    axis.axhline(drawn(result.centralized.terr_mean), color="tab:orange", linestyle="--",
                 label=f"{result.labels[reference]}, {mode} EKF")
    axis.set_xlabel("robot-to-robot messages per robot-step (constant: 4)")
    axis.set_ylabel("Terr (m)")
    axis.set_title(f"{result.scenario}: {result.trials} trials, means from step {result.settle}", fontsize=10)
    axis.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
