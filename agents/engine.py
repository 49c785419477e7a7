"""The in-process engine: a whole team, or a batch of trials, stepped with no processes and no bus.

It runs exactly the per-robot sequence of a robot process for every robot at once, through the
scenario's strategy (:mod:`agents.strategy`): measure and estimate (:mod:`agents.estimation`),
observe and poll (the strategy's controller) with neighbour replies read straight from the true
step-start positions and beliefs, fuse, move
(:meth:`world.geometry.ConvexRegion.move_along`). Arrays are indexed ``[step - 1, trial, robot]``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ringtrack.agents.controller import CentreUncertainty
from ringtrack.agents.estimation import Estimators, Told, team_steady_variance
from ringtrack.agents.relay import VELOCITY_WINDOW_S, RangeRelay
from ringtrack.agents.strategy import Received, Strategy, check_strategy, strategy_for
from ringtrack.bus.faults import FAULT_COUNTERS, FAULTS, Fates, FaultPlan, fate_counts, published_copies
from ringtrack.bus.messages import robot_message_bytes, uint_bytes
from ringtrack.bus.radio import message_bits, receive_energy, transmit_energy
from ringtrack.world.elementwise import anywhere, everywhere
from ringtrack.world.geometry import FloatArray, angle_of
from ringtrack.world.metrics import (
    converged,
    convergence_error,
    convergence_step,
    mean_communication_rate,
    memory_cerr,
    strategy_cerr,
    target_error,
)
from ringtrack.world.ranges import link_distance
from ringtrack.world.ring import midpoint_errors, predecessor_values, successor_values
from ringtrack.world.scenario import Scenario
from ringtrack.world.sensing import RangeSensors
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
    estimates (or ``None`` when not recorded) and ``covariances`` the covariance of each (m^2, packed
    ``xx, xy, yy`` as commands carry it; NaN where the robots know the target); the request copies
    each robot published to its predecessor and successor (``requests``, None when read from a log)
    and the beliefs it pushed them (``pushes``), the robot-to-robot traffic that follows per robot
    (``sent``, ``received``: :func:`ring_traffic` and the pushes), the fault
    layer's counts (``faults``), ``probes`` of unreachable neighbours, the bytes of the
    robot-to-robot messages each robot published and the radio energy of each robot's traffic
    (see :func:`exchange`).
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
    sent_bytes: NDArray[np.int64] | None = None  # (K, T, N) bytes of the robot-to-robot messages each published
    energy: FloatArray | None = None  # (K, T, N, 2) radio energy, J: transmit, receive (None: not known)
    pushes: NDArray[np.int64] | None = None  # (K, T, N, 2) beliefs pushed to predecessor, successor (None: a log)
    covariances: FloatArray | None = None  # (K, T, N, 3) xx, xy, yy of each estimate, m^2 (None: not recorded)

    @property
    def steps(self) -> int:
        return self.angles.shape[0]

    def select(self, trials: slice, scenario: Scenario | None = None) -> History:
        """The history of some of the trials (as if run alone, for the steps this batch ran),
        labelled with ``scenario`` (default this one's)."""
        arrays: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            arrays[name] = value[:, trials] if isinstance(value, np.ndarray) else value
        arrays["scenario"] = scenario or self.scenario
        arrays["seeds"] = self.seeds[trials]
        return History(**arrays)

    @property
    def cerr_memory(self) -> FloatArray:
        """Cerr from each live robot's memory before polling (degrees, shape (K, T); NaN where a
        live robot's offset is unknown)."""
        return memory_cerr(self.offsets, self.live)

    @property
    def cerr(self) -> FloatArray:
        """The paper's Cerr of the run's strategy, as the strategy says (:attr:`Strategy.cerr`: the
        memory-based Cerr, or the true one for the constant strategy)."""
        return strategy_cerr(strategy_for(self.scenario.strategy).cerr, self.cerr_memory, self.cerr_true)

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


WINDOW = 100


class TeamEstimate:
    """The estimators of a batch of teams, exactly as the processes hold them: none ("known": the
    robots steer about the true stationary target), one per trial (the fusion centre), or one per
    robot (decentralized); all of them one batch of filters (:class:`agents.estimation.Estimators`)."""

    def __init__(self, scenario: Scenario, seeds: list[int], paths: FloatArray) -> None:
        self.mode = scenario.estimation.mode
        self.robots = scenario.robots
        self.trials = len(seeds)
        sensing = scenario.spec.sensing
        self.sensors = RangeSensors(sensing.range_sigma, sensing.range, seeds)
        count = {"known": 0, "centralized": 1, "decentralized": scenario.robots}[self.mode]
        self.estimators = Estimators(scenario.estimation, scenario.region, np.repeat(paths[:, 0], count, axis=0))
        relays = self.mode == "decentralized" and strategy_for(scenario.strategy).relays
        window = round(VELOCITY_WINDOW_S / scenario.control.dt)
        self.relay = RangeRelay(self.trials, self.robots, paths.shape[1], window) if relays else None
        self.step = 0

    def measure(self, positions: FloatArray, targets: FloatArray, strategy: Strategy | None = None,
                told: tuple[NDArray[np.bool_], NDArray[np.bool_]] | None = None,
                told_beliefs: tuple[FloatArray, FloatArray] | None = None) -> FloatArray:
        """Measure ranges and update every filter; returns the centres to steer about (T, N, 2).
        With a listening ``strategy``, decentralized robots also hear (:meth:`Strategy.hear`) the
        beliefs ``told_beliefs`` (every robot's, as it told them) that their predecessor and successor
        told them (``told``, per side) in the previous step, predecessor first."""
        if self.mode == "known":
            return np.repeat(targets[:, None, :], self.robots, axis=1)
        ranges = self.sensors.measure(positions, targets)  # (T, N)
        self.step += 1
        if self.mode == "centralized":
            self.estimators.measure(positions, ranges)
            return np.repeat(self.estimators.centre[:, None, :], self.robots, axis=1)
        robots = self.trials * self.robots
        here = positions.reshape(robots, 1, 2), ranges.reshape(robots, 1)
        if strategy is not None and told is not None and told_beliefs is not None:
            strategy.hear(self.estimators, *here, self._told(told, told_beliefs))
        elif self.relay is not None:
            params = self.estimators.params
            late = self.relay.take(self.step, self.estimators.centre, params.range_sigma, params.process_noise)
            self.relay.record(self.step, positions, ranges)
            self.estimators.measure(*here, late=late)
        else:
            self.estimators.measure(*here)
        return self.estimators.centre.reshape(positions.shape)

    def _told(self, sides: tuple[NDArray[np.bool_], NDArray[np.bool_]],
              beliefs: tuple[FloatArray, FloatArray]) -> Told:
        """What every robot's (predecessor, successor) told it, as the filters' slots: ``sides`` say
        who told (T, N) per side, ``beliefs`` every robot's told belief (T, N, 2), (T, N, 2, 2)."""
        means, covariances = beliefs
        robots = self.trials * self.robots
        return Told(_sides_of(means).reshape(robots, 2, 2), _sides_of(covariances).reshape(robots, 2, 2, 2),
                    _pair(*sides).reshape(robots, 2))

    def beliefs(self) -> tuple[FloatArray, FloatArray]:
        """Every decentralized robot's belief now: means (T, N, 2) metres, covariances (T, N, 2, 2) m^2."""
        mean, covariance = self.estimators.belief
        return mean.reshape(self.trials, -1, 2), covariance.reshape(self.trials, -1, 2, 2)

    def covariances(self) -> FloatArray:
        """The covariance of the estimate every robot steers by, (T, N, 3) packed ``xx, xy, yy``
        (m^2) as its command carries it: its own belief (decentralized), the fusion centre's
        (centralized), NaN (known)."""
        if self.mode == "known":
            return np.full((self.trials, self.robots, 3), np.nan)
        covariance = self.estimators.belief[1].reshape(self.trials, -1, 2, 2)
        packed = np.stack([covariance[..., 0, 0], covariance[..., 0, 1], covariance[..., 1, 1]], axis=-1)
        return np.broadcast_to(packed, (self.trials, self.robots, 3))

    def target_error(self, centres: FloatArray, targets: FloatArray) -> FloatArray:
        """Terr of every trial (metres, (T,)) of the ``centres`` the robots steer about (T, N, 2)
        against the true ``targets`` (T, 2): :func:`world.metrics.target_error`, which is exactly 0
        where the robots steer about the target itself (known)."""
        if self.mode == "known":
            return np.zeros(self.trials)
        return target_error(centres, targets)

    def fuse(self, fresh_minus: NDArray[np.bool_], fresh_plus: NDArray[np.bool_], centres: FloatArray) -> bool:
        """Decentralized robots fuse the beliefs of the neighbours whose replies reached them (beliefs
        as they were before anyone fused this step) and steer by the result; ``centres`` is updated
        in place. Whether any robot fused (else every centre is as it was)."""
        fusing = self.mode == "decentralized" and self.relay is None
        if not (fusing and (anywhere(fresh_minus) or anywhere(fresh_plus))):
            return False
        self.estimators.fuse(self._told((fresh_minus, fresh_plus), self.beliefs()))
        centres[...] = self.estimators.centre.reshape(centres.shape)
        return True


FAULT_COLUMNS = FAULT_COUNTERS  # sent, delivered, dropped, duplicated, delayed, published


def ring_traffic(requests: NDArray[np.int64]) -> NDArray[np.int64]:
    """Robot-to-robot messages each robot publishes in a step, from the request copies each one
    published to its predecessor (``[..., 0]``) and successor (``[..., 1]``), robots on axis -2:
    its requests, and one reply to each request copy its neighbours sent it
    (:func:`bus.faults.request_traffic`). By symmetry each robot also receives exactly as many."""
    requests = requests.astype(np.int64)
    return requests[..., 0] + requests[..., 1] + _to_neighbours(requests)


def _to_neighbours(per_side: NDArray) -> NDArray:
    """Values of each robot's (predecessor, successor) sides, shape (..., T, N, 2), summed onto the
    neighbour at the other end of each link, shape (..., T, N)."""
    return successor_values(per_side[..., 0]) + predecessor_values(per_side[..., 1])


def robot_to_robot_sent(polled: np.ndarray) -> np.ndarray:
    """Messages each robot publishes in a step without faults (``polled`` boolean, robots last):
    2 requests when it polls, and one reply to each ring neighbour that polls it."""
    return ring_traffic(np.stack([polled, polled], axis=-1))


def fault_totals(history: History, trial: int = 0, steps: slice = slice(None)) -> dict[str, int]:
    """Robot-to-robot messages sent, delivered, dropped, duplicated, delayed and published over the
    ``steps`` (rows of the history; default all) of a trial, and probes."""
    totals = history.faults[steps, trial].sum(axis=0)
    return {**{name: int(value) for name, value in zip(FAULT_COLUMNS, totals, strict=True)},
            "probes": int(history.probes[steps, trial].sum())}


def link_traffic(history: History, trial: int = 0) -> list[tuple[str, str, str, int, None]]:
    """Robot-to-robot traffic rows ``(kind, source, destination, messages, None)`` of a trial, per
    link with any traffic, as a monitor counts them on the bus (no bytes: nothing was sent)."""
    assert history.requests is not None, "per-link traffic is known of engine runs only"
    robots = history.requests.shape[2]
    copies = history.requests[:, trial].sum(axis=0)
    pushed = np.zeros_like(copies) if history.pushes is None else history.pushes[:, trial].sum(axis=0)
    rows: list[tuple[str, str, str, int, None]] = []
    for robot in range(robots):
        for side, neighbour in ((0, (robot - 1) % robots), (1, (robot + 1) % robots)):
            if copies[robot, side]:
                rows.append(("request", f"r{robot}", f"r{neighbour}", int(copies[robot, side]), None))
                rows.append(("reply", f"r{neighbour}", f"r{robot}", int(copies[robot, side]), None))
            if pushed[robot, side]:
                rows.append(("push", f"r{robot}", f"r{neighbour}", int(pushed[robot, side]), None))
    return rows


@dataclass
class Exchange:
    """What the polls and probes of one step achieved, for a batch of teams: which sides came back
    fresh, the request copies each robot published per side (predecessor, successor; each answered
    by one reply), the fault counts per trial (:data:`FAULT_COLUMNS`), the probes of unreachable
    neighbours per trial, the bytes of the robot-to-robot messages each robot published and each
    robot's radio energy (joules, transmit and receive, last axis)."""

    fresh_minus: NDArray[np.bool_]
    fresh_plus: NDArray[np.bool_]
    requests: NDArray[np.int64]
    faults: NDArray[np.int64]
    probes: NDArray[np.int64]
    sent_bytes: NDArray[np.int64]
    energy: FloatArray
    pushes: NDArray[np.int64]  # (T, N, 2) beliefs each robot pushed to its predecessor, successor
    push_delivered: NDArray[np.bool_]  # (T, N, 2) ... that reached them


PlanGroups = list[tuple[FaultPlan, NDArray[np.int64]]]  # distinct fault plans and the trials of each


def exchange(plan: FaultPlan | PlanGroups, step: int, polled: NDArray[np.bool_], reach_minus: NDArray[np.bool_],
             reach_plus: NDArray[np.bool_], distance_minus: FloatArray | None = None,
             distance_plus: FloatArray | None = None, seeds: NDArray[np.int64] | None = None,
             belief: bool = False, pushed: NDArray[np.bool_] | None = None,
             request_belief: bool = False, content: FloatArray | None = None,
             relayed: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None) -> Exchange:
    """Settle the requests and replies of a step as the robots' fault layers do (:mod:`bus.faults`,
    :class:`bus.shim.LinkShim`, counted by the same rule, :func:`bus.faults.fate_counts`), for every
    robot of every trial at once: a polling robot requests both neighbours; a robot also probes
    each unreachable neighbour once (its poll request serving as the probe); a request to an
    unreachable neighbour is dropped, every published copy of a request is answered
    (:func:`bus.faults.published_copies`), and each reply meets its own fate on arrival. Links are
    ``distance_minus``/``distance_plus`` metres long (to the predecessor, successor; default 0),
    trial t draws its fates with plan seed ``seeds[t]`` (default the plan's), replies carry a
    belief when ``belief`` and requests when ``request_belief``; replies carry the ``content`` of
    a strategy (the floats each robot's replies carry, ``(T, N, fields)``; see
    :func:`bus.messages.robot_message_bytes`); ``relayed`` gives instead the sizes (bytes, (T, N, 2))
    of every robot's requests to its (predecessor, successor) and of their replies to it, for
    messages that carry ranges (:meth:`agents.relay.RangeRelay.message_bytes`).
    ``pushed`` (per side) are the beliefs robots push unasked: each is published once and meets its
    fate on arrival, like a reply. ``plan`` may also give groups of trials their own plans (one
    radio for all). Energy, from the same fates: every copy put on the
    bus costs its sender transmission (a request dropped before publishing was still sent once),
    every copy delivered costs its receiver reception (:mod:`bus.radio`), with the exact encoded
    size of each message."""
    trials, robots = polled.shape
    reach = _pair(reach_minus, reach_plus)
    requested = polled[..., None] | ~reach
    if not anywhere(requested) and (pushed is None or not anywhere(pushed)):
        return _silent(reach.shape)
    distance = (np.zeros(reach.shape) if distance_minus is None or distance_plus is None
                else _pair(distance_minus, distance_plus))
    robot, neighbour = _ring_sides(robots)
    groups = [(plan, np.arange(trials))] if isinstance(plan, FaultPlan) else plan
    pushing = pushed is not None and anywhere(pushed)
    if not pushing and not any(group.active for group, _ in groups) and everywhere(reach):
        # No fault, no push, every neighbour in reach: each request is delivered once and answered by
        # one delivered reply, so every message sent is delivered and published (fate_counts' rule).
        requests = requested.astype(np.int64)
        sent = 2 * requests.sum(axis=(1, 2))
        faults = np.zeros((trials, len(FAULT_COLUMNS)), dtype=np.int64)
        for column in ("sent", "delivered", "published"):
            faults[:, FAULT_COLUMNS.index(column)] = sent
        fresh, replies_delivered, on_air = requested, requests, requests
        pushes, push_delivered = np.zeros(reach.shape, np.int64), np.zeros(reach.shape, dtype=bool)
    else:
        seed = None if seeds is None else np.asarray(seeds)[:, None, None]
        request = _group_fates(groups, "request", robot, neighbour, step, distance, seed, reach.shape)
        reply = _group_fates(groups, "reply", neighbour, robot, step, distance, seed, reach.shape)
        lost = ~reach | request.dropped  # out of range: dropped before sending, as the fault layer does
        requests = np.where(requested, published_copies(lost, request.copies), 0)  # each answered by one reply
        of_requests = fate_counts(lost, request.copies, request.delay_s, requested)
        of_replies = reply.counts(requests)
        pushes = np.zeros(reach.shape, np.int64) if pushed is None else pushed.astype(np.int64)
        push = (_group_fates(groups, "push", robot, neighbour, step, distance, seed, reach.shape) if pushing
                else _undisturbed(reach.shape))
        counts = {name: of_requests[name] + of_replies[name] for name in (*FAULTS, "delivered")}
        if pushing:
            of_pushes = push.counts(pushes)
            counts = {name: counts[name] + of_pushes[name] for name in counts}
        counts["sent"] = requested.astype(np.int64) + requests + pushes
        counts["published"] = ring_traffic(requests) + pushes[..., 0] + pushes[..., 1]
        per_message = np.stack([counts[name] for name in FAULT_COLUMNS[:-1]], axis=-1).sum(axis=(1, 2))  # (T, 5)
        faults = np.concatenate([per_message, counts["published"].sum(axis=1)[:, None]], axis=1)
        fresh = (requests > 0) & ~reply.dropped
        replies_delivered, on_air = of_replies["delivered"], np.where(requested, np.maximum(requests, 1), 0)
        push_delivered = (pushes > 0) & ~push.dropped
    radio = groups[0][0].radio
    request_bytes = _ring_message_bytes("request", step, robots, request_belief)
    sides = None if content is None else _sides_of(content)  # what (predecessor, successor) carry
    reply_bytes = (_ring_message_bytes("reply", step, robots, belief) if sides is None
                   else robot_message_bytes("reply", step, neighbour, robot, belief, sides))
    if relayed is not None:
        request_bytes, reply_bytes = relayed
    request_bits, reply_bits = message_bits(radio, request_bytes), message_bits(radio, reply_bytes)
    # Per side of each robot: what it sends and receives itself, and what its neighbour on that side does.
    # (np.array of equal shapes stacks them as np.stack does, without its cost per call)
    own = np.array([requests * request_bytes, on_air * transmit_energy(radio, request_bits, distance),
                    replies_delivered * receive_energy(radio, reply_bits)])
    other = np.array([requests * reply_bytes, requests * transmit_energy(radio, reply_bits, distance),
                      requests * receive_energy(radio, request_bits)])
    if pushing:
        push_bytes = _ring_message_bytes("push", step, robots, False)
        push_bits = message_bits(radio, push_bytes)
        own = own + np.array([pushes * push_bytes, pushes * transmit_energy(radio, push_bits, distance),
                              np.zeros(reach.shape)])
        other = other + np.array([np.zeros(reach.shape), np.zeros(reach.shape),
                                  of_pushes["delivered"] * receive_energy(radio, push_bits)])
    totals = own[..., 0] + own[..., 1] + _to_neighbours(other)  # both sides
    return Exchange(fresh[..., 0], fresh[..., 1], requests, faults.astype(np.int64), (~reach).sum(axis=(1, 2)),
                    totals[0].astype(np.int64), _pair(totals[1], totals[2]), pushes, push_delivered)


def _silent(shape: tuple[int, int, int]) -> Exchange:
    """The exchange of a step in which no robot requests or pushes anything (shape (T, N, 2)): no
    message, no fault, no energy."""
    trials, robots = shape[:2]
    nothing = np.zeros(shape, dtype=np.int64)
    return Exchange(np.zeros((trials, robots), dtype=bool), np.zeros((trials, robots), dtype=bool), nothing,
                    np.zeros((trials, len(FAULT_COLUMNS)), dtype=np.int64), np.zeros(trials, dtype=np.int64),
                    np.zeros((trials, robots), dtype=np.int64), np.zeros(shape), nothing.copy(),
                    np.zeros(shape, dtype=bool))


def _pair(minus: NDArray, plus: NDArray) -> NDArray:
    """``np.stack([minus, plus], axis=-1)`` of two arrays of one shape (per side: predecessor,
    successor), without its cost per call."""
    pair = np.empty(np.shape(minus) + (2,), dtype=np.result_type(minus, plus))
    pair[..., 0], pair[..., 1] = minus, plus
    return pair


def _ring_message_bytes(kind: str, step: int, robots: int, belief: bool) -> NDArray[np.int64]:
    """:func:`bus.messages.robot_message_bytes` of a step's ``kind`` messages from every robot of a
    ring of ``robots`` to its (predecessor, successor) (replies: from them), shape (1, N, 2), read-only;
    they depend on the step only through its encoded size, which keys a cache."""
    key = (kind, int(uint_bytes(step)), robots, belief)
    if key not in _RING_MESSAGE_BYTES:
        robot, neighbour = _ring_sides(robots)
        sender, receiver = (neighbour, robot) if kind == "reply" else (robot, neighbour)
        sizes = np.asarray(robot_message_bytes(kind, step, sender, receiver, belief), dtype=np.int64)
        sizes.setflags(write=False)
        _RING_MESSAGE_BYTES[key] = sizes
    return _RING_MESSAGE_BYTES[key]


_RING_MESSAGE_BYTES: dict[tuple[str, int, int, bool], NDArray[np.int64]] = {}  # see _ring_message_bytes


@lru_cache(maxsize=8)
def _ring_sides(robots: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Each robot's id and its (predecessor, successor) ids, shapes (1, N, 1) and (1, N, 2)."""
    robot = np.arange(robots)[None, :, None]
    return robot, (robot + np.array([-1, 1])) % robots


def _group_fates(groups: PlanGroups, kind: str, sender: NDArray[np.int64], receiver: NDArray[np.int64], step: int,
                 distance: FloatArray, seed: NDArray[np.int64] | None, shape: tuple[int, ...]) -> Fates:
    """The fates of a step's ``kind`` messages of every trial, each group of trials by its plan."""
    if len(groups) == 1 and len(groups[0][1]) == shape[0]:
        plan = groups[0][0]
        if not plan.active:
            return _undisturbed(shape)
        return plan.decide(kind, sender, receiver, step, distance, seed)
    fates = Fates(np.zeros(shape, np.int8), np.ones(shape, np.int64), np.zeros(shape))
    for plan, trials in groups:
        if plan.active:
            part = plan.decide(kind, sender, receiver, step, distance[trials], None if seed is None else seed[trials])
            fates.reason[trials], fates.copies[trials], fates.delay_s[trials] = part.reason, part.copies, part.delay_s
    return fates


@lru_cache(maxsize=16)
def _undisturbed(shape: tuple[int, ...]) -> Fates:
    """Fates of messages no fault touches (each delivered once, at once), read-only, by shape."""
    fates = Fates(np.zeros(shape, np.int8), np.ones(shape, np.int64), np.zeros(shape))
    for values in (fates.reason, fates.copies, fates.delay_s):
        values.setflags(write=False)
    return fates


def _plan_groups(plans: list[FaultPlan], trials: int) -> PlanGroups:
    """The distinct plans (by identity) and the trials of each; they must share one radio."""
    if len(plans) != trials:
        raise ValueError(f"{len(plans)} fault plans for {trials} trials; give one per trial")
    if len({plan.radio for plan in plans}) > 1:
        raise ValueError("the trials' fault plans have different radios; run them apart")
    first: dict[int, int] = {}
    for trial, plan in enumerate(plans):
        first.setdefault(id(plan), trial)
    return [(plans[trial], np.array([t for t, plan in enumerate(plans) if id(plan) == id(plans[trial])]))
            for trial in first.values()]


def fault_seeds(scenario: Scenario, seeds: Sequence[int]) -> NDArray[np.int64]:
    """The fault plan's seed of each trial: ``[faults] seed`` when the scenario sets it, else the
    trial's seed (what ``--seed`` gives a single run), so trial t equals a run with seed t."""
    fixed = scenario.spec.faults.seed
    return np.array([fixed if fixed is not None else seed for seed in seeds], dtype=np.int64)


def run(
    scenario: Scenario,
    seeds: Sequence[int] | int | None = None,
    steps: int | None = None,
    until_converged: bool = False,
    record_positions: bool = True,
    on_step: StepObserver | None = None,
    plans: Sequence[FaultPlan] | None = None,
    watch: Callable[[int, Any, FloatArray], None] | None = None,
) -> History:
    """Run ``scenario`` for each seed (default: the scenario's own) as one vectorised batch.

    ``steps`` defaults to ``scenario.max_steps``; with ``until_converged`` the batch stops at the
    first step by which every trial has converged. ``on_step(k)`` is called after each step (progress).
    ``plans`` gives each trial its own fault plan (default: the scenario's for all), so that runs
    that differ only in their faults share one batch (:meth:`History.select` splits it again).
    ``watch(k, controller, positions)`` is called after each step's observe with the true step-start
    positions (tests check invariants of the robots' memory every step).
    """
    seeds = [scenario.seed] if seeds is None else [seeds] if isinstance(seeds, int) else list(seeds)
    steps = scenario.max_steps if steps is None else steps
    region, params = scenario.region, scenario.control
    threshold_deg = np.rad2deg(scenario.threshold)

    paths = np.stack([scenario.target_path(seed, steps) for seed in seeds])  # (T, K, 2)
    positions = np.stack([scenario.start_positions(seed) for seed in seeds])
    trials, robots = positions.shape[:2]
    strategy = check_strategy(scenario)
    team = TeamEstimate(scenario, seeds, paths)
    controller = strategy.controller(region, params, positions)
    angles = np.empty((steps, trials, robots))
    triggers = np.empty((steps, trials, robots), dtype=np.uint8)
    offsets = np.empty((steps, trials, robots))
    ages = np.empty((steps, trials, robots, 2), dtype=np.int32)
    cerr_true = np.empty((steps, trials))
    terr = np.empty((steps, trials))
    requests = np.empty((steps, trials, robots, 2), dtype=np.int64)
    faults = np.empty((steps, trials, len(FAULT_COLUMNS)), dtype=np.int64)
    probes = np.empty((steps, trials), dtype=np.int64)
    sent_bytes = np.empty((steps, trials, robots), dtype=np.int64)
    energy = np.empty((steps, trials, robots, 2))
    pushes = np.zeros((steps, trials, robots, 2), dtype=np.int64)
    # A listening strategy: what each robot was told in the previous step (per side) and everyone's
    # belief as told; a pushing one: the belief each robot last told its neighbours.
    no_one = np.zeros((trials, robots), dtype=bool)
    told, told_beliefs = (no_one, no_one), team.beliefs()
    last_told = team.beliefs() if strategy.pushes else None
    plan_seeds = fault_seeds(scenario, seeds)
    groups = _plan_groups([scenario.faults] * trials if plans is None else list(plans), trials)
    belief = scenario.estimation.mode == "decentralized"
    reads_uncertainty = strategy.reads_uncertainty and belief
    steady_variance = team_steady_variance(scenario.estimation, robots) if reads_uncertainty else None
    limit = scenario.communication_range
    recorded = np.empty((steps, trials, robots, 2)) if record_positions else None
    estimates = np.empty((steps, trials, robots, 2)) if record_positions else None
    covariances = np.empty((steps, trials, robots, 3)) if record_positions else None
    done = np.zeros(trials, dtype=bool)

    for k in range(1, steps + 1):
        row = k - 1
        targets = paths[:, row]
        if recorded is not None:
            recorded[row] = positions
        angles[row] = angle_of(positions, targets[:, None, :])
        cerr_true[row] = convergence_error(midpoint_errors(angles[row]))  # world.metrics.true_cerr, of these angles
        if strategy.listens:
            centres = team.measure(positions, targets, strategy, told, told_beliefs)
            told_beliefs = team.beliefs()  # what this step's requests, replies and pushes carry
        else:
            centres = team.measure(positions, targets)
        neighbours = _to_sides(positions)
        lengths = link_distance(positions, neighbours[0]), link_distance(positions, neighbours[1])
        reach = lengths[0] <= (limit or np.inf), lengths[1] <= (limit or np.inf)
        uncertainty = (None if steady_variance is None
                       else CentreUncertainty(team.beliefs()[1], steady_variance))
        # a team: an array
        reasons = np.asarray(controller.observe(k, positions, centres, reach, uncertainty=uncertainty))
        triggers[row] = reasons
        ages[row, ..., 0], ages[row, ..., 1] = controller.predecessor_age, controller.successor_age
        if watch is not None:
            watch(k, controller, positions)
        polled = reasons != 0
        # What each robot's replies of this step carry, read once it has observed the step.
        content = strategy.reply_content(controller) if strategy.reply_fields else None
        pushed = None
        if last_told is not None:
            pushing = ~polled & strategy.wants_push(told_beliefs[0], *last_told, scenario.estimation)
            pushed = pushing[..., None] & _pair(*reach)
            telling = polled | pushing
            last_told = (np.where(telling[..., None], told_beliefs[0], last_told[0]),
                         np.where(telling[..., None, None], told_beliefs[1], last_told[1]))
        relayed = None if team.relay is None else team.relay.message_bytes(k)
        outcome = exchange(groups, k, polled, *reach, *lengths, plan_seeds, belief, pushed, strategy.listens,
                           content, relayed)
        if strategy.listens or team.relay is not None:
            # told by the predecessor's message to its successor, and the other way
            reached = (outcome.requests > 0) | outcome.push_delivered
            told = predecessor_values(reached[..., 1], axis=1), successor_values(reached[..., 0], axis=1)
        if team.relay is not None:  # requests and replies carry ranges
            team.relay.hand_over(told[0] | outcome.fresh_minus, told[1] | outcome.fresh_plus)
        if strategy.pushes:  # else none pushed: the rows stay zero
            pushes[row] = outcome.pushes
        strategy.receive(controller, *replies(neighbours, outcome, content))
        if team.fuse(outcome.fresh_minus, outcome.fresh_plus, centres):
            controller.recentre(centres)
        goal = controller.goal(reach if limit else None, limit)
        requests[row], faults[row], probes[row] = outcome.requests, outcome.faults, outcome.probes
        sent_bytes[row], energy[row] = outcome.sent_bytes, outcome.energy
        offsets[row] = np.where(controller.offset_known, controller.guaranteed_offset, np.nan)
        terr[row] = team.target_error(centres, targets)
        if estimates is not None and covariances is not None:
            estimates[row], covariances[row] = centres, team.covariances()
        positions = motion_step(scenario, positions, goal)
        if on_step is not None:
            on_step(k)
        done |= converged(strategy_cerr(strategy.cerr, memory_cerr(offsets[row]), cerr_true[row]), threshold_deg)
        if until_converged and everywhere(done):
            steps = k
            break

    traffic = ring_traffic(requests[:steps])  # each robot's requests and replies: as many sent as received
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
        sent=traffic + pushes[:steps, ..., 0] + pushes[:steps, ..., 1] if strategy.pushes else traffic,
        received=traffic + _to_neighbours(pushes[:steps]) if strategy.pushes else traffic.copy(),
        requests=requests[:steps],
        faults=faults[:steps],
        probes=probes[:steps],
        sent_bytes=sent_bytes[:steps],
        energy=energy[:steps],
        pushes=pushes[:steps],
        covariances=None if covariances is None else covariances[:steps],
    )


def replies(neighbours: tuple[FloatArray, FloatArray], outcome: Exchange,
            content: FloatArray | None) -> tuple[Received, Received]:
    """What came back to every robot from its predecessor and successor in a step: their step-start
    ``neighbours`` positions (metres) where the reply came, and the ``content`` every robot's
    replies carry (``(T, N, fields)``, robots on axis 1; None: a strategy whose replies carry nothing)."""
    carried = (None, None) if content is None else _to_sides(content)
    return (Received(neighbours[0], outcome.fresh_minus, np.zeros(outcome.fresh_minus.shape, dtype=np.int64),
                     carried[0]),
            Received(neighbours[1], outcome.fresh_plus, np.zeros(outcome.fresh_plus.shape, dtype=np.int64),
                     carried[1]))


def _to_sides(values: NDArray) -> tuple[NDArray, NDArray]:
    """What each robot's predecessor and successor hold of ``values`` (robots on axis 1)."""
    return predecessor_values(values, axis=1), successor_values(values, axis=1)


def _sides_of(values: NDArray) -> NDArray:
    """:func:`_to_sides` as one array, the sides on a new axis 2 (predecessor, successor): shape
    (T, N, 2, ...) of ``values`` (T, N, ...)."""
    return np.take(values, _ring_sides(values.shape[1])[1][0], axis=1)
