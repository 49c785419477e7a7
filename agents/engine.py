"""The in-process engine: a whole team, or a batch of trials, stepped with no processes and no bus.

It runs exactly the per-robot sequence of a robot process for every robot at once: measure and
estimate (:mod:`agents.estimation`), observe and poll (:class:`agents.controller.MidpointController`)
with neighbour replies read straight from the true step-start positions and beliefs, fuse, move
(:meth:`world.geometry.ConvexRegion.move_along`). Arrays are indexed ``[step - 1, trial, robot]``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ringtrack.agents.controller import MidpointController
from ringtrack.agents.estimation import Estimator
from ringtrack.bus.faults import FAULT_COUNTERS, POLL_MESSAGES, Fate, FaultCounter, FaultPlan
from ringtrack.world.geometry import FloatArray, angle_of
from ringtrack.world.metrics import (
    converged,
    convergence_step,
    mean_communication_rate,
    memory_cerr,
    strategy_cerr,
    target_error,
    true_cerr,
)
from ringtrack.world.scenario import Scenario
from ringtrack.world.sensing import RangeSensor
from ringtrack.world.state import motion_step


@dataclass
class History:
    """Per-step record of a batch of runs of one scenario.

    ``angles`` are radians about the true target, unwrapped along time; ``positions`` metres (or
    ``None`` when not recorded); ``live`` the robots in the ring (the engine's team is always
    whole; a logged one may lose robots); ``triggers`` the :class:`agents.laws.Trigger` masks; ``offsets`` each
    robot's ``gV - theta`` (radians) from memory before polling (NaN while it knows nothing of a
    neighbour) and ``ages`` its memory ages (steps,
    predecessor and successor) at that moment; ``cerr_true`` degrees (see
    :mod:`world.metrics`); ``targets`` the true target; ``terr`` the target error (metres, the mean
    over robots of the distance from the estimate each steered by to the target); ``estimates`` those
    estimates (or ``None`` when not recorded); the request copies each robot published to its
    predecessor and successor (``requests``, None when read from a log), the robot-to-robot traffic
    that follows from them per robot (``sent``, ``received``: :func:`ring_traffic`), the fault
    layer's counts (``faults``) and ``probes`` of unreachable neighbours (see :func:`exchange`).
    """

    scenario: Scenario
    seeds: list[int]
    angles: FloatArray  # (K, T, N)
    positions: FloatArray | None  # (K, T, N, 2)
    live: NDArray[np.bool_]  # (K, T, N)
    triggers: NDArray[np.uint8]  # (K, T, N)
    offsets: FloatArray  # (K, T, N)
    ages: NDArray[np.int32]  # (K, T, N, 2)
    cerr_true: FloatArray  # (K, T)
    targets: FloatArray  # (K, T, 2)
    terr: FloatArray  # (K, T)
    estimates: FloatArray | None  # (K, T, N, 2)
    sent: NDArray[np.int64]  # (K, T, N) robot-to-robot messages published by each robot
    received: NDArray[np.int64]  # (K, T, N) ... addressed to each robot
    requests: NDArray[np.int64] | None  # (K, T, N, 2) request copies to predecessor, successor (None: a log)
    faults: NDArray[np.int64]  # (K, T, 6) FAULT_COLUMNS
    probes: NDArray[np.int64]  # (K, T) requests to unreachable neighbours

    @property
    def steps(self) -> int:
        return self.angles.shape[0]

    @property
    def cerr_memory(self) -> FloatArray:
        """Cerr from each live robot's memory before polling (degrees, shape (K, T); NaN where a
        live robot's offset is unknown)."""
        return memory_cerr(self.offsets, self.live)

    @property
    def cerr(self) -> FloatArray:
        """The paper's Cerr of the run's strategy: memory-based for "self", true for "constant"."""
        return strategy_cerr(self.scenario.control.strategy, self.cerr_memory, self.cerr_true)

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


class TeamEstimate:
    """The estimators of a batch of teams, exactly as the processes hold them: none ("known": the
    robots steer about the true stationary target), one per trial (the fusion centre), or one per
    robot (decentralized)."""

    def __init__(self, scenario: Scenario, seeds: list[int], paths: FloatArray) -> None:
        self.mode = scenario.estimation.mode
        self.robots = scenario.robots
        sensing = scenario.spec.sensing
        self.sensors = [RangeSensor(sensing.range_sigma, sensing.range, seed) for seed in seeds]
        count = {"known": 0, "centralized": 1, "decentralized": scenario.robots}[self.mode]
        self.estimators = [
            [Estimator(scenario.estimation, scenario.region, paths[trial, 0]) for _ in range(count)]
            for trial in range(len(seeds))
        ]

    def measure(self, positions: FloatArray, targets: FloatArray) -> FloatArray:
        """Measure ranges and update every filter; returns the centres to steer about (T, N, 2)."""
        if self.mode == "known":
            return np.repeat(targets[:, None, :], self.robots, axis=1)
        centres = np.empty_like(positions)
        for trial, (sensor, estimators) in enumerate(zip(self.sensors, self.estimators, strict=True)):
            ranges = sensor.measure(positions[trial], targets[trial])
            if self.mode == "centralized":
                estimators[0].measure(positions[trial], ranges)
                centres[trial] = estimators[0].centre
            else:
                for robot, estimator in enumerate(estimators):
                    estimator.measure(positions[trial, robot : robot + 1], ranges[robot : robot + 1])
                    centres[trial, robot] = estimator.centre
        return centres

    def fuse(self, fresh_minus: NDArray[np.bool_], fresh_plus: NDArray[np.bool_], centres: FloatArray) -> None:
        """Decentralized robots fuse the beliefs of the neighbours whose replies reached them (beliefs
        as they were before anyone fused this step) and steer by the result; ``centres`` is updated
        in place."""
        if self.mode != "decentralized":
            return
        for trial, estimators in enumerate(self.estimators):
            beliefs = [estimator.belief for estimator in estimators]
            for robot in np.flatnonzero(fresh_minus[trial] | fresh_plus[trial]):
                sides = ((fresh_minus, robot - 1), (fresh_plus, robot + 1))
                received = [beliefs[neighbour % self.robots] for fresh, neighbour in sides if fresh[trial, robot]]
                estimators[robot].fuse(received)
                centres[trial, robot] = estimators[robot].centre


FAULT_COLUMNS = FAULT_COUNTERS  # sent, delivered, dropped, duplicated, delayed, published


def ring_traffic(requests: NDArray[np.int64]) -> NDArray[np.int64]:
    """Robot-to-robot messages each robot publishes in a step, from the request copies each one
    published to its predecessor (``[..., 0]``) and successor (``[..., 1]``), robots on axis -2:
    its requests, and one reply to each request copy its neighbours sent it
    (:func:`bus.faults.request_traffic`). By symmetry each robot also receives exactly as many."""
    requests = requests.astype(np.int64)
    replies = np.roll(requests[..., 1], 1, axis=-1) + np.roll(requests[..., 0], -1, axis=-1)
    return requests.sum(axis=-1) + replies


def robot_to_robot_sent(polled: np.ndarray) -> np.ndarray:
    """Messages each robot publishes in a step without faults (``polled`` boolean, robots last):
    2 requests when it polls, and one reply to each ring neighbour that polls it."""
    return ring_traffic(np.stack([polled, polled], axis=-1))


def fault_totals(history: History, trial: int = 0) -> dict[str, int]:
    """Robot-to-robot messages sent, delivered, dropped, duplicated, delayed and published over a
    trial, and probes."""
    totals = history.faults[:, trial].sum(axis=0)
    return {**{name: int(value) for name, value in zip(FAULT_COLUMNS, totals, strict=True)},
            "probes": int(history.probes[:, trial].sum())}


def link_traffic(history: History, trial: int = 0) -> list[tuple[str, str, str, int, None]]:
    """Robot-to-robot traffic rows ``(kind, source, destination, messages, None)`` of a trial, per
    link with any traffic, as a monitor counts them on the bus (no bytes: nothing was sent)."""
    assert history.requests is not None, "per-link traffic is known of engine runs only"
    robots = history.requests.shape[2]
    copies = history.requests[:, trial].sum(axis=0)
    rows: list[tuple[str, str, str, int, None]] = []
    for robot in range(robots):
        for side, neighbour in ((0, (robot - 1) % robots), (1, (robot + 1) % robots)):
            if copies[robot, side]:
                rows.append(("request", f"r{robot}", f"r{neighbour}", int(copies[robot, side]), None))
                rows.append(("reply", f"r{neighbour}", f"r{robot}", int(copies[robot, side]), None))
    return rows


@dataclass
class Exchange:
    """What the polls and probes of one step achieved, for a batch of teams: which sides came back
    fresh, the request copies each robot published per side (predecessor, successor; each answered
    by one reply), the fault counts per trial (:data:`FAULT_COLUMNS`) and the probes of unreachable
    neighbours per trial."""

    fresh_minus: NDArray[np.bool_]
    fresh_plus: NDArray[np.bool_]
    requests: NDArray[np.int64]
    faults: NDArray[np.int64]
    probes: NDArray[np.int64]


def exchange(plan: FaultPlan, step: int, polled: NDArray[np.bool_], reach_minus: NDArray[np.bool_],
             reach_plus: NDArray[np.bool_]) -> Exchange:
    """Settle the requests and replies of a step as the robots' fault layers do (:mod:`bus.faults`,
    :class:`bus.shim.LinkShim`, counted by the same :class:`~bus.faults.FaultCounter`): a polling
    robot requests both neighbours; a robot also probes each unreachable neighbour once (its poll
    request serving as the probe); a request to an unreachable neighbour is dropped, every
    delivered copy of a request is answered, and each reply meets its own fate on arrival."""
    trials, robots = polled.shape
    requests = np.zeros((trials, robots, 2), dtype=np.int64)
    if not plan.active and reach_minus.all() and reach_plus.all():
        requests[...] = polled[..., None]
        faults = np.zeros((trials, len(FAULT_COLUMNS)), dtype=np.int64)
        messages = POLL_MESSAGES * polled.sum(axis=1)
        for name in ("sent", "delivered", "published"):
            faults[:, FAULT_COLUMNS.index(name)] = messages
        return Exchange(polled, polled, requests, faults, np.zeros(trials, dtype=np.int64))
    fresh = {-1: np.zeros_like(polled), 1: np.zeros_like(polled)}
    counters = [FaultCounter() for _ in range(trials)]
    probes = np.zeros(trials, dtype=np.int64)
    for trial, robot in zip(*np.nonzero(polled | ~reach_minus | ~reach_plus), strict=True):
        counter = counters[trial]
        for index, (side, reachable) in enumerate(((-1, reach_minus[trial, robot]), (1, reach_plus[trial, robot]))):
            if reachable and not polled[trial, robot]:
                continue
            neighbour = (robot + side) % robots
            probes[trial] += not reachable
            fate = plan.fate("request", robot, neighbour, step) if reachable else Fate(dropped=True, reason="range")
            copies = 0 if fate.dropped else fate.copies
            counter.count_sent(copies)
            counter.count_fate(fate)
            requests[trial, robot, index] = copies
            if fate.dropped:
                continue
            counter.count_delivered(copies)
            answer = plan.fate("reply", neighbour, robot, step)
            for _ in range(copies):  # every delivered copy is answered; each answer meets the same fate
                counter.count_sent(1)
                counter.count_fate(answer)
                counter.count_delivered(0 if answer.dropped else answer.copies)
            fresh[side][trial, robot] = not answer.dropped
    faults = np.array([[counter.counts[name] for name in FAULT_COLUMNS] for counter in counters], dtype=np.int64)
    return Exchange(fresh[-1], fresh[1], requests, faults, probes)


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
    region, params = scenario.region, scenario.control
    threshold_deg = np.rad2deg(scenario.threshold)

    paths = np.stack([scenario.target_path(seed, steps) for seed in seeds])  # (T, K, 2)
    positions = np.stack([scenario.start_positions(seed) for seed in seeds])
    trials, robots = positions.shape[:2]
    team = TeamEstimate(scenario, seeds, paths)
    controller = MidpointController(region, params, positions)
    angles = np.empty((steps, trials, robots))
    triggers = np.empty((steps, trials, robots), dtype=np.uint8)
    offsets = np.empty((steps, trials, robots))
    ages = np.empty((steps, trials, robots, 2), dtype=np.int32)
    cerr_true = np.empty((steps, trials))
    terr = np.empty((steps, trials))
    requests = np.empty((steps, trials, robots, 2), dtype=np.int64)
    faults = np.empty((steps, trials, len(FAULT_COLUMNS)), dtype=np.int64)
    probes = np.empty((steps, trials), dtype=np.int64)
    limit = scenario.communication_range
    recorded = np.empty((steps, trials, robots, 2)) if record_positions else None
    estimates = np.empty((steps, trials, robots, 2)) if record_positions else None
    done = np.zeros(trials, dtype=bool)

    for k in range(1, steps + 1):
        row = k - 1
        targets = paths[:, row]
        if recorded is not None:
            recorded[row] = positions
        angles[row] = angle_of(positions, targets[:, None, :])
        cerr_true[row] = true_cerr(positions, targets)
        centres = team.measure(positions, targets)
        neighbours = np.roll(positions, 1, axis=1), np.roll(positions, -1, axis=1)
        reach = tuple(np.linalg.norm(neighbour - positions, axis=-1) <= (limit or np.inf) for neighbour in neighbours)
        reasons = controller.observe(k, positions, centres, reach)
        triggers[row] = reasons
        ages[row, ..., 0], ages[row, ..., 1] = controller.predecessor_age, controller.successor_age
        polled = reasons != 0
        outcome = exchange(scenario.faults, k, polled, *reach)
        controller.receive(*neighbours, outcome.fresh_minus, outcome.fresh_plus)
        if team.mode == "decentralized":
            team.fuse(outcome.fresh_minus, outcome.fresh_plus, centres)
            controller.recentre(centres)
        goal = controller.goal(reach if limit else None, limit)
        requests[row], faults[row], probes[row] = outcome.requests, outcome.faults, outcome.probes
        offsets[row] = np.where(controller.offset_known, controller.guaranteed_offset, np.nan)
        terr[row] = target_error(centres, targets)
        if estimates is not None:
            estimates[row] = centres
        positions = motion_step(scenario, positions, goal)
        if on_step is not None:
            on_step(k)
        done |= converged(strategy_cerr(params.strategy, memory_cerr(offsets[row]), cerr_true[row]), threshold_deg)
        if until_converged and done.all():
            steps = k
            break

    return History(
        scenario=scenario,
        seeds=seeds,
        angles=np.unwrap(angles[:steps], axis=0),
        positions=None if recorded is None else recorded[:steps],
        live=np.ones((steps, trials, robots), dtype=bool),
        triggers=triggers[:steps],
        offsets=offsets[:steps],
        ages=ages[:steps],
        cerr_true=cerr_true[:steps],
        targets=np.swapaxes(paths[:, :steps], 0, 1),
        terr=terr[:steps],
        estimates=None if estimates is None else estimates[:steps],
        sent=ring_traffic(requests[:steps]),
        received=ring_traffic(requests[:steps]),
        requests=requests[:steps],
        faults=faults[:steps],
        probes=probes[:steps],
    )


def summary(history: History, trial: int = 0) -> dict[str, object]:
    """The JSON-ready summary of one trial of a run: convergence, communication and final error."""
    scenario = history.scenario
    ctime = int(history.ctime[trial])
    ctime_true = int(history.ctime_true[trial])
    polled = (history.triggers[:, trial] != 0).sum(axis=0)
    com_bar = float(history.com_bar[trial])
    return {
        "scenario": scenario.name,
        "strategy": scenario.control.strategy,
        "law": scenario.control.law,
        "robots": int(history.angles.shape[2]),
        "seed": history.seeds[trial],
        "steps": history.steps,
        "threshold_deg": float(np.rad2deg(scenario.threshold)),
        "converged": ctime > 0,
        "ctime": ctime or None,
        "ctime_true": ctime_true or None,
        "com_bar": com_bar if ctime else None,
        "triggers": {"total": int(polled.sum()), "per_robot": polled.tolist()},
        "cerr_final_deg": _known(history.cerr[-1, trial]),
        "cerr_true_final_deg": float(history.cerr_true[-1, trial]),
        "estimation": scenario.estimation.mode,
        "terr_mean": float(history.terr[:, trial].mean()),
        "terr_final": float(history.terr[-1, trial]),
        "faults": fault_totals(history, trial),
    }


def _known(value: float) -> float | None:
    """A figure for JSON: None where it is unknown (NaN)."""
    return None if np.isnan(value) else float(value)
