"""The in-process engine: a whole team, or a batch of trials, stepped with no processes and no bus.

It runs exactly the per-robot sequence of a robot process (:class:`agents.controller.MidpointController`)
for every robot at once, with neighbour replies read straight from the true step-start positions,
and the world's motion step (:meth:`world.geometry.ConvexRegion.move_along`). Arrays are indexed
``[step - 1, trial, robot]``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agents.controller import MidpointController
from world.geometry import FloatArray, angle_of
from world.metrics import convergence_error, convergence_step, mean_communication_rate, true_offsets
from world.scenario import Scenario


@dataclass
class History:
    """Per-step record of a batch of runs of one scenario.

    ``angles`` are radians about the true target, unwrapped along time; ``positions`` metres (or
    ``None`` when not recorded); ``triggers`` the :class:`agents.laws.Trigger` masks; ``cerr_true`` and
    ``cerr_memory`` degrees (see :mod:`world.metrics`).
    """

    scenario: Scenario
    seeds: list[int]
    angles: FloatArray  # (K, T, N)
    positions: FloatArray | None  # (K, T, N, 2)
    triggers: NDArray[np.uint8]  # (K, T, N)
    cerr_true: FloatArray  # (K, T)
    cerr_memory: FloatArray  # (K, T)

    @property
    def steps(self) -> int:
        return self.angles.shape[0]

    @property
    def cerr(self) -> FloatArray:
        """The paper's Cerr of the run's strategy: memory-based for "self", true for "constant"."""
        return self.cerr_memory if self.scenario.control.strategy == "self" else self.cerr_true

    @property
    def ctime(self) -> NDArray[np.int64]:
        """Ctime per trial on the paper's Cerr (0: not converged within the steps run)."""
        return convergence_step(self.cerr, np.rad2deg(self.scenario.threshold))

    @property
    def ctime_true(self) -> NDArray[np.int64]:
        """Ctime per trial on the true Cerr."""
        return convergence_step(self.cerr_true, np.rad2deg(self.scenario.threshold))

    @property
    def com_bar(self) -> FloatArray:
        """Com-bar per trial (NaN where not converged)."""
        return mean_communication_rate(self.triggers, self.ctime)


StepObserver = Callable[[int], None]


def run(
    scenario: Scenario,
    seeds: Sequence[int] | int | None = None,
    steps: int | None = None,
    until_converged: bool = False,
    record_positions: bool = True,
    on_step: StepObserver | None = None,
) -> History:
    """Run ``scenario`` for each seed (default: the scenario's own) as one vectorised batch.

    ``steps`` defaults to ``scenario.max_steps``; with ``until_converged`` the batch stops at the
    first step by which every trial has converged. ``on_step(k)`` is called after each step (progress).
    """
    seeds = [scenario.seed] if seeds is None else [seeds] if isinstance(seeds, int) else list(seeds)
    steps = scenario.max_steps if steps is None else steps
    region, params, target = scenario.region, scenario.control, scenario.target
    threshold_deg = np.rad2deg(scenario.threshold)
    max_move = None if scenario.v_max is None else scenario.v_max * params.dt

    positions = np.stack([scenario.start_positions(seed) for seed in seeds])
    trials, robots = positions.shape[:2]
    controller = MidpointController(
        region, params, np.roll(positions, 1, axis=1), np.roll(positions, -1, axis=1)
    )
    angles = np.empty((steps, trials, robots))
    triggers = np.empty((steps, trials, robots), dtype=np.uint8)
    cerr_true = np.empty((steps, trials))
    cerr_memory = np.empty((steps, trials))
    recorded = np.empty((steps, trials, robots, 2)) if record_positions else None
    converged = np.zeros(trials, dtype=bool)
    paper_cerr = cerr_memory if params.strategy == "self" else cerr_true

    for k in range(1, steps + 1):
        row = k - 1
        if recorded is not None:
            recorded[row] = positions
        angles[row] = angle_of(positions, target)
        cerr_true[row] = convergence_error(true_offsets(positions, target))
        reasons = controller.observe(k, positions, target)
        cerr_memory[row] = convergence_error(controller.guaranteed_offset)
        triggers[row] = reasons
        controller.receive(reasons != 0, np.roll(positions, 1, axis=1), np.roll(positions, -1, axis=1))
        positions = region.move_along(positions, controller.goal(positions, target), max_move)
        if on_step is not None:
            on_step(k)
        converged |= paper_cerr[row] < threshold_deg
        if until_converged and converged.all():
            steps = k
            break

    return History(
        scenario=scenario,
        seeds=seeds,
        angles=np.unwrap(angles[:steps], axis=0),
        positions=None if recorded is None else recorded[:steps],
        triggers=triggers[:steps],
        cerr_true=cerr_true[:steps],
        cerr_memory=cerr_memory[:steps],
    )
