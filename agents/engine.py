"""The in-process engine: a whole team, or a batch of trials, stepped with no processes and no bus.

It runs exactly the per-robot sequence of a robot process for every robot at once, through the
scenario's strategy (:mod:`agents.strategy`): measure and estimate (:mod:`agents.estimation`),
observe and poll (the strategy's controller) with neighbour replies read straight from the true
step-start positions and beliefs, fuse, move
(:meth:`world.geometry.ConvexRegion.move_along`). A :class:`Batch` holds the state between steps
and runs one (:meth:`Batch.step`); :func:`run` records every step of a uniform batch as a
:class:`History` (arrays indexed ``[step - 1, trial, robot]``); :func:`run_until_converged` runs
teams of several sizes as one ragged batch (:mod:`agents.layout`), keeping per team only what a
stationary study reads (:class:`TeamSeries`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import msgspec
import numpy as np
from numpy.typing import NDArray

from ringtrack.agents.controller import CentreUncertainty, MidpointController
from ringtrack.agents.estimation import Estimators, Told, team_steady_variance
from ringtrack.agents.layout import Layout
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
from ringtrack.world.ring import midpoint_errors
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

    def __init__(self, scenario: Scenario, seeds: list[int], paths: FloatArray, layout: Layout) -> None:
        if layout.ragged and scenario.estimation.mode != "known":
            raise ValueError("a ragged batch's robots know the target: its teams have no estimators")
        self.mode = scenario.estimation.mode
        self.layout = layout
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

    def keep(self, layout: Layout) -> None:
        """Teams left a ragged batch, now laid out as ``layout``: its robots know the target, so
        there is nothing else to keep."""
        self.layout, self.trials = layout, layout.trials

    def measure(self, positions: FloatArray, targets: FloatArray, strategy: Strategy | None = None,
                told: tuple[NDArray[np.bool_], NDArray[np.bool_]] | None = None,
                told_beliefs: tuple[FloatArray, FloatArray] | None = None) -> FloatArray:
        """Measure ranges and update every filter; returns the centres to steer about (T, N, 2).
        With a listening ``strategy``, decentralized robots also hear (:meth:`Strategy.hear`) the
        beliefs ``told_beliefs`` (every robot's, as it told them) that their predecessor and successor
        told them (``told``, per side) in the previous step, predecessor first."""
        if self.mode == "known":
            return self.layout.spread(targets)
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
        return Told(self.layout.sides(means).reshape(robots, 2, 2),
                    self.layout.sides(covariances).reshape(robots, 2, 2, 2),
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


def ring_traffic(requests: NDArray[np.int64], layout: Layout | None = None) -> NDArray[np.int64]:
    """Robot-to-robot messages each robot publishes in a step, from the request copies each one
    published to its predecessor (``[..., 0]``) and successor (``[..., 1]``), robots on axis -2
    (laid out by ``layout``; default: one ring of them):
    its requests, and one reply to each request copy its neighbours sent it
    (:func:`bus.faults.request_traffic`). By symmetry each robot also receives exactly as many."""
    requests = requests.astype(np.int64)
    return requests[..., 0] + requests[..., 1] + _to_neighbours(requests, layout)


def _to_neighbours(per_side: NDArray, layout: Layout | None = None) -> NDArray:
    """Values of each robot's (predecessor, successor) sides, shape (..., T, N, 2), summed onto the
    neighbour at the other end of each link, shape (..., T, N) (robots laid out by ``layout``;
    default: one ring of them)."""
    rings = Layout.uniform(1, per_side.shape[-2]) if layout is None else layout
    return rings.successor(per_side[..., 0], axis=-1) + rings.predecessor(per_side[..., 1], axis=-1)


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
             relayed: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
             layout: Layout | None = None) -> Exchange:
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
    size of each message. ``layout`` lays the teams out (default: uniform, ``polled`` (T, N))."""
    layout = Layout.uniform(*polled.shape) if layout is None else layout
    trials = layout.trials
    reach = _pair(reach_minus, reach_plus)
    requested = polled[..., None] | ~reach
    if not anywhere(requested) and (pushed is None or not anywhere(pushed)):
        return _silent(reach.shape, trials)
    distance = (np.zeros(reach.shape) if distance_minus is None or distance_plus is None
                else _pair(distance_minus, distance_plus))
    robot, neighbour = layout.ids
    groups = [(plan, np.arange(trials))] if isinstance(plan, FaultPlan) else plan
    pushing = pushed is not None and anywhere(pushed)
    if not pushing and not any(group.active for group, _ in groups) and everywhere(reach):
        # No fault, no push, every neighbour in reach: each request is delivered once and answered by
        # one delivered reply, so every message sent is delivered and published (fate_counts' rule).
        requests = requested.astype(np.int64)
        sent = 2 * layout.team_sum(requests).sum(axis=-1)
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
        counts["published"] = ring_traffic(requests, layout) + pushes[..., 0] + pushes[..., 1]
        per_message = layout.team_sum(np.stack([counts[name] for name in FAULT_COLUMNS[:-1]], axis=-1)).sum(axis=1)
        faults = np.concatenate([per_message, layout.team_sum(counts["published"])[:, None]], axis=1)  # (T, 6)
        fresh = (requests > 0) & ~reply.dropped
        replies_delivered, on_air = of_replies["delivered"], np.where(requested, np.maximum(requests, 1), 0)
        push_delivered = (pushes > 0) & ~push.dropped
    radio = groups[0][0].radio
    request_bytes = _ring_message_bytes("request", step, layout, request_belief)
    sides = None if content is None else layout.sides(content)  # what (predecessor, successor) carry
    reply_bytes = (_ring_message_bytes("reply", step, layout, belief) if sides is None
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
        push_bytes = _ring_message_bytes("push", step, layout, False)
        push_bits = message_bits(radio, push_bytes)
        own = own + np.array([pushes * push_bytes, pushes * transmit_energy(radio, push_bits, distance),
                              np.zeros(reach.shape)])
        other = other + np.array([np.zeros(reach.shape), np.zeros(reach.shape),
                                  of_pushes["delivered"] * receive_energy(radio, push_bits)])
    totals = own[..., 0] + own[..., 1] + _to_neighbours(other, layout)  # both sides
    return Exchange(fresh[..., 0], fresh[..., 1], requests, faults.astype(np.int64),
                    layout.team_sum(~reach).sum(axis=-1),
                    totals[0].astype(np.int64), _pair(totals[1], totals[2]), pushes, push_delivered)


def _silent(shape: tuple[int, int, int], trials: int) -> Exchange:
    """The exchange of a step in which no robot of ``trials`` teams requests or pushes anything
    (per-robot shape (T, N, 2)): no message, no fault, no energy."""
    per_robot = shape[:2]
    nothing = np.zeros(shape, dtype=np.int64)
    return Exchange(np.zeros(per_robot, dtype=bool), np.zeros(per_robot, dtype=bool), nothing,
                    np.zeros((trials, len(FAULT_COLUMNS)), dtype=np.int64), np.zeros(trials, dtype=np.int64),
                    np.zeros(per_robot, dtype=np.int64), np.zeros(shape), nothing.copy(),
                    np.zeros(shape, dtype=bool))


def _pair(minus: NDArray, plus: NDArray) -> NDArray:
    """``np.stack([minus, plus], axis=-1)`` of two arrays of one shape (per side: predecessor,
    successor), without its cost per call."""
    pair = np.empty(np.shape(minus) + (2,), dtype=np.result_type(minus, plus))
    pair[..., 0], pair[..., 1] = minus, plus
    return pair


def _ring_message_bytes(kind: str, step: int, layout: Layout, belief: bool) -> NDArray[np.int64]:
    """:func:`bus.messages.robot_message_bytes` of a step's ``kind`` messages from every robot of
    the ``layout``'s rings to its (predecessor, successor) (replies: from them), shape (1, N, 2),
    read-only; they depend on the step only through its encoded size, which keys a cache (a uniform
    layout's by its team size, shared by every batch; a ragged one's its own)."""
    key = (kind, int(uint_bytes(step)), layout.robots, belief)
    cache = layout.cache if layout.ragged else _RING_MESSAGE_BYTES
    if key not in cache:
        robot, neighbour = layout.ids
        sender, receiver = (neighbour, robot) if kind == "reply" else (robot, neighbour)
        sizes = np.asarray(robot_message_bytes(kind, step, sender, receiver, belief), dtype=np.int64)
        sizes.setflags(write=False)
        cache[key] = sizes
    return cache[key]


_RING_MESSAGE_BYTES: dict[tuple[str, int, int, bool], NDArray[np.int64]] = {}  # see _ring_message_bytes


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


@dataclass
class StepRecord:
    """What one step of a :class:`Batch` came to: the step-start ``positions`` (metres), the
    robots' true ``angles`` about the target (radians) and each team's true Cerr (degrees), the
    ``centres`` the robots steered about (metres), their trigger ``reasons``, their memory ages
    (steps, predecessor and successor) after observing, the step's robot-to-robot :class:`Exchange`,
    each robot's ``gV - theta`` from memory before polling (radians, NaN while unknown) and each
    team's Terr (metres). Per robot: the layout's shape; per team: (T,)."""

    positions: FloatArray
    angles: FloatArray
    cerr_true: FloatArray
    centres: FloatArray
    reasons: NDArray[np.int64]
    ages: tuple[NDArray[np.int64], NDArray[np.int64]]
    outcome: Exchange
    offsets: FloatArray
    terr: FloatArray


class Batch:
    """A batch of runs of a scenario between steps: the robots' true positions and the targets'
    paths, the robots' memories (the strategy's controller), their estimators and what they last
    told one another, for teams laid out by a :class:`agents.layout.Layout`. :meth:`step` runs one
    step of every robot at once, as :func:`run` records it.

    ``seeds`` start the trials (one team each); ``steps`` bounds the targets' paths; ``plans``
    gives each trial its own fault plan (default: the scenario's for all). The teams are laid out
    uniform, all of the scenario's size, unless ``scenarios`` gives each trial's own (a ragged batch:
    build it with :meth:`of_teams`, which checks they may share one)."""

    def __init__(self, scenario: Scenario, seeds: list[int], steps: int, plans: Sequence[FaultPlan] | None = None,
                 scenarios: Sequence[Scenario] | None = None) -> None:
        self.scenario = scenario
        if scenarios is None:
            own, layout = [scenario] * len(seeds), Layout.uniform(len(seeds), scenario.robots)
            self.positions = np.stack([scenario.start_positions(seed) for seed in seeds])  # (T, N, 2)
        else:
            own, layout = list(scenarios), Layout.of_teams([each.robots for each in scenarios])
            self.positions = np.concatenate([each.start_positions(seed)
                                             for each, seed in zip(own, seeds, strict=True)])[None]  # (1, R, 2)
        self.paths = np.stack([each.target_path(seed, steps) for each, seed in zip(own, seeds, strict=True)])
        self.layout = layout
        self.kept: NDArray[np.intp] | None = None  # the trials (of paths, seeds) a ragged batch still runs
        trials = layout.trials
        self.strategy = strategy = check_strategy(scenario)
        self.team = TeamEstimate(scenario, seeds, self.paths, layout)
        self.controller = strategy.controller(scenario.region, scenario.control, self.positions)
        # A listening strategy: what each robot was told in the previous step (per side) and everyone's
        # belief as told; a pushing one: the belief each robot last told its neighbours.
        no_one = np.zeros(layout.shape, dtype=bool)
        self.told, self.told_beliefs = (no_one, no_one), self.team.beliefs()
        self.last_told = self.team.beliefs() if strategy.pushes else None
        self.plan_seeds = fault_seeds(scenario, seeds)
        self.groups = _plan_groups([scenario.faults] * trials if plans is None else list(plans), trials)
        self.belief = scenario.estimation.mode == "decentralized"
        reads_uncertainty = strategy.reads_uncertainty and self.belief
        self.steady_variance = (team_steady_variance(scenario.estimation, scenario.robots) if reads_uncertainty
                                else None)
        self.limit = scenario.communication_range

    @classmethod
    def of_teams(cls, scenarios: Sequence[Scenario], seeds: Sequence[int], steps: int) -> Batch:
        """Trial t runs ``scenarios[t]`` from ``seeds[t]``, the teams laid out ragged (teams of one
        size best given together): scenarios that differ only in their team (its size, its start),
        whose robots know the target and whose strategy neither listens, pushes nor relays, with
        no fault and no communication range (:class:`ValueError` otherwise). Each team's run is the
        same as in a uniform batch of its own scenario."""
        refusal = ragged_refusal(scenarios)
        if refusal is not None:
            raise ValueError(refusal)
        return cls(scenarios[0], list(seeds), steps, scenarios=scenarios)

    @property
    def keeps(self) -> bool:
        """Whether :meth:`keep` can let teams leave: a ragged batch whose robots' memory is the
        midpoint strategies' own (:meth:`agents.controller.MidpointController.keep`; a strategy's
        controller of its own may hold more, and keeps every robot)."""
        return self.layout.ragged and type(self.controller) is MidpointController

    def keep(self, teams: NDArray[np.bool_]) -> None:
        """Go on with the ``teams`` kept only (a mask of the batch's teams, in its order; see
        :attr:`keeps`): the robots of the others leave the batch, the rest run on as before."""
        if not self.keeps:
            raise ValueError("only a ragged batch whose robots' memory is the midpoint strategies' lets teams leave")
        assert isinstance(self.controller, MidpointController)
        self.layout, robots = self.layout.keep(teams)
        self.kept = np.flatnonzero(teams) if self.kept is None else self.kept[teams]
        self.positions = self.positions[:, robots]
        self.controller.keep(robots)
        self.team.keep(self.layout)
        no_one = np.zeros(self.layout.shape, dtype=bool)
        self.told = (no_one, no_one)  # nobody listens in a ragged batch
        self.plan_seeds = self.plan_seeds[teams]
        self.groups = [(self.groups[0][0], np.arange(self.layout.trials))]  # one plan, which drops nothing

    def step(self, k: int, watch: Callable[[int, Any, FloatArray], None] | None = None) -> StepRecord:
        """Run step ``k`` (1-based) of every robot: measure and estimate, observe and poll, settle
        the exchange, take the replies, fuse and move; ``watch(k, controller, positions)`` is called
        after observing (see :func:`run`)."""
        layout, team, controller, strategy, limit = self.layout, self.team, self.controller, self.strategy, self.limit
        positions = self.positions
        row = k - 1
        targets = self.paths[:, row] if self.kept is None else self.paths[self.kept, row]
        angles = angle_of(positions, layout.per_robot(targets))
        # world.metrics.true_cerr, of these angles
        cerr_true = convergence_error(midpoint_errors(angles, layout.successor, layout.predecessor), layout.team_sum)
        if strategy.listens:
            centres = team.measure(positions, targets, strategy, self.told, self.told_beliefs)
            self.told_beliefs = team.beliefs()  # what this step's requests, replies and pushes carry
        else:
            centres = team.measure(positions, targets)
        neighbours = layout.predecessor(positions), layout.successor(positions)
        lengths = link_distance(positions, neighbours[0]), link_distance(positions, neighbours[1])
        reach = lengths[0] <= (limit or np.inf), lengths[1] <= (limit or np.inf)
        uncertainty = (None if self.steady_variance is None
                       else CentreUncertainty(team.beliefs()[1], self.steady_variance))
        # a team: an array
        reasons = np.asarray(controller.observe(k, positions, centres, reach, uncertainty=uncertainty))
        ages = controller.predecessor_age, controller.successor_age
        if watch is not None:
            watch(k, controller, positions)
        polled = reasons != 0
        # What each robot's replies of this step carry, read once it has observed the step.
        content = strategy.reply_content(controller) if strategy.reply_fields else None
        pushed = None
        if self.last_told is not None:
            told_beliefs, last_told = self.told_beliefs, self.last_told
            pushing = ~polled & strategy.wants_push(told_beliefs[0], *last_told, self.scenario.estimation)
            pushed = pushing[..., None] & _pair(*reach)
            telling = polled | pushing
            self.last_told = (np.where(telling[..., None], told_beliefs[0], last_told[0]),
                              np.where(telling[..., None, None], told_beliefs[1], last_told[1]))
        relayed = None if team.relay is None else team.relay.message_bytes(k)
        outcome = exchange(self.groups, k, polled, *reach, *lengths, self.plan_seeds, self.belief, pushed,
                           strategy.listens, content, relayed, layout)
        if strategy.listens or team.relay is not None:
            # told by the predecessor's message to its successor, and the other way
            reached = (outcome.requests > 0) | outcome.push_delivered
            self.told = layout.predecessor(reached[..., 1]), layout.successor(reached[..., 0])
        if team.relay is not None:  # requests and replies carry ranges
            team.relay.hand_over(self.told[0] | outcome.fresh_minus, self.told[1] | outcome.fresh_plus)
        strategy.receive(controller, *replies(neighbours, outcome, content, layout))
        if team.fuse(outcome.fresh_minus, outcome.fresh_plus, centres):
            controller.recentre(centres)
        goal = controller.goal(reach if limit else None, limit)
        offsets = np.where(controller.offset_known, controller.guaranteed_offset, np.nan)
        terr = team.target_error(centres, targets)
        self.positions = motion_step(self.scenario, positions, goal)
        return StepRecord(positions, angles, cerr_true, centres, reasons, ages, outcome, offsets, terr)

    def cerr(self, record: StepRecord) -> FloatArray:
        """The paper's Cerr of every team at a step (degrees, (T,)): its strategy's
        (:func:`world.metrics.strategy_cerr`)."""
        return strategy_cerr(self.strategy.cerr, memory_cerr(record.offsets, team_sum=self.layout.team_sum),
                             record.cerr_true)


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
    threshold_deg = np.rad2deg(scenario.threshold)
    batch = Batch(scenario, seeds, steps, plans)
    trials, robots = batch.layout.shape
    strategy, team = batch.strategy, batch.team
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
    recorded = np.empty((steps, trials, robots, 2)) if record_positions else None
    estimates = np.empty((steps, trials, robots, 2)) if record_positions else None
    covariances = np.empty((steps, trials, robots, 3)) if record_positions else None
    done = np.zeros(trials, dtype=bool)

    for k in range(1, steps + 1):
        row = k - 1
        record = batch.step(k, watch)
        outcome = record.outcome
        if recorded is not None:
            recorded[row] = record.positions
        angles[row], cerr_true[row], triggers[row] = record.angles, record.cerr_true, record.reasons
        ages[row, ..., 0], ages[row, ..., 1] = record.ages
        if strategy.pushes:  # else none pushed: the rows stay zero
            pushes[row] = outcome.pushes
        requests[row], faults[row], probes[row] = outcome.requests, outcome.faults, outcome.probes
        sent_bytes[row], energy[row] = outcome.sent_bytes, outcome.energy
        offsets[row], terr[row] = record.offsets, record.terr
        if estimates is not None and covariances is not None:
            estimates[row], covariances[row] = record.centres, team.covariances()
        if on_step is not None:
            on_step(k)
        done |= converged(batch.cerr(record), threshold_deg)
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
        targets=np.swapaxes(batch.paths[:, :steps], 0, 1),
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


@dataclass
class TeamSeries:
    """Per step (row k - 1 for step k) and team (columns) of runs until each team converged
    (:func:`run_until_converged`): the paper's Cerr of the team's strategy (``cerr``) and the true
    Cerr (degrees), the robots that polled and the bytes of the robot-to-robot messages the team's
    robots published; ``ctime`` is each team's Ctime (0: it did not converge, and ran every step).
    A team's rows end at its Ctime: the rows after it hold NaN (Cerr) and 0."""

    cerr: FloatArray
    cerr_true: FloatArray
    polls: NDArray[np.int64]
    sent_bytes: NDArray[np.int64]
    ctime: NDArray[np.int64]

    @classmethod
    def of_history(cls, history: History) -> TeamSeries:
        """The series of a batch's history, each trial's rows ended at its Ctime."""
        assert history.sent_bytes is not None, "engine runs count bytes"
        return cls(history.cerr, history.cerr_true, (history.triggers != 0).sum(axis=2),
                   history.sent_bytes.sum(axis=2), history.ctime).ended()

    def ended(self) -> TeamSeries:
        """These series with each team's rows after its Ctime blanked (NaN, 0)."""
        after = np.arange(len(self.cerr))[:, None] >= np.where(self.ctime > 0, self.ctime, len(self.cerr))
        return TeamSeries(np.where(after, np.nan, self.cerr), np.where(after, np.nan, self.cerr_true),
                          np.where(after, 0, self.polls), np.where(after, 0, self.sent_bytes), self.ctime)

    def trimmed(self, steps: int) -> TeamSeries:
        """These series' first ``steps`` rows."""
        return TeamSeries(self.cerr[:steps], self.cerr_true[:steps], self.polls[:steps], self.sent_bytes[:steps],
                          self.ctime)

    @staticmethod
    def joined(parts: Sequence[tuple[NDArray[np.intp], TeamSeries]]) -> TeamSeries:
        """One series of the teams of several (each ``(its teams' columns, its series)``), as long as
        the longest."""
        steps = max(len(part.cerr) for _, part in parts)
        teams = sum(len(columns) for columns, _ in parts)
        joined = TeamSeries(np.full((steps, teams), np.nan), np.full((steps, teams), np.nan),
                            np.zeros((steps, teams), np.int64), np.zeros((steps, teams), np.int64),
                            np.zeros(teams, np.int64))
        for columns, part in parts:
            rows = len(part.cerr)
            joined.cerr[:rows, columns], joined.cerr_true[:rows, columns] = part.cerr, part.cerr_true
            joined.polls[:rows, columns], joined.sent_bytes[:rows, columns] = part.polls, part.sent_bytes
            joined.ctime[columns] = part.ctime
        return joined


# Teams that converged leave a ragged batch once their robots are this share of those it steps.
LEAVING_SHARE = 0.1


def run_until_converged(scenarios: Sequence[Scenario], seeds: Sequence[int]) -> TeamSeries:
    """Run trial t, ``scenarios[t]`` from ``seeds[t]``, until it converges (at most its scenario's
    ``max_steps``) and return the :class:`TeamSeries` of every trial, each the same as a batch of
    its scenario alone gives (:func:`run` with ``until_converged``).

    Teams of scenarios that may share a ragged batch (:func:`ragged_refusal`: a sweep over team
    sizes) run as one, converged teams leaving it as it goes where their memory allows
    (:attr:`Batch.keeps`): a step of it costs about the robots it holds, not its number of team
    sizes. Other scenarios run as a uniform batch each (:func:`uniform_series`)."""
    if ragged_refusal(scenarios) is not None:
        return uniform_series(scenarios, seeds)
    steps = max(each.max_steps for each in scenarios)
    return _ragged_series(Batch.of_teams(scenarios, seeds, steps), np.rad2deg([each.threshold for each in scenarios]),
                          steps)


def ragged_refusal(scenarios: Sequence[Scenario]) -> str | None:
    """Why the teams of ``scenarios`` cannot share a ragged batch (None: they can): they must
    differ only in their ``[team]`` (its size, its start), their robots must know the target, their
    strategy neither listen, push nor relay, and they must have no fault and no communication range."""
    first = scenarios[0]
    strategy = check_strategy(first)
    unlike = next((each for each in scenarios
                   if msgspec.structs.replace(each.spec, team=first.spec.team) != first.spec), None)
    if unlike is not None:
        return f"{unlike.name}: teams of one ragged batch may differ only in [team]"
    if first.estimation.mode != "known" or strategy.listens or strategy.pushes or strategy.relays:
        return ("a ragged batch runs robots that know the target, with a strategy that neither listens, pushes "
                "nor relays")
    if first.faults.active:
        return "a ragged batch runs without faults"
    if first.communication_range is not None:
        return "a ragged batch runs without a communication range"
    return None


def uniform_series(scenarios: Sequence[Scenario], seeds: Sequence[int]) -> TeamSeries:
    """The :class:`TeamSeries` of trial t, ``scenarios[t]`` from ``seeds[t]``, run until it
    converged in a uniform batch of the trials of its scenario (the same object)."""
    parts = []
    for scenario in {id(each): each for each in scenarios}.values():  # each distinct scenario once, in order
        columns = np.array([index for index, each in enumerate(scenarios) if each is scenario])
        history = run(scenario, [seeds[index] for index in columns], until_converged=True, record_positions=False)
        parts.append((columns, TeamSeries.of_history(history)))
    return TeamSeries.joined(parts)


def _ragged_series(batch: Batch, thresholds_deg: FloatArray, steps: int) -> TeamSeries:
    """The :class:`TeamSeries` of a ragged ``batch`` run until every team converged below its
    threshold (degrees) or ``steps`` ran; converged teams leave it (:meth:`Batch.keep`)."""
    teams = batch.layout.trials
    series = TeamSeries(np.full((steps, teams), np.nan), np.full((steps, teams), np.nan),
                        np.zeros((steps, teams), np.int64), np.zeros((steps, teams), np.int64),
                        np.zeros(teams, np.int64))
    present = np.arange(teams)  # the batch's teams, in its order
    running = np.ones(teams, dtype=bool)  # of those, the ones that have not converged
    for k in range(1, steps + 1):
        row = k - 1
        record = batch.step(k)
        cerr = batch.cerr(record)
        on = present[running]
        series.cerr[row, on], series.cerr_true[row, on] = cerr[running], record.cerr_true[running]
        series.polls[row, on] = batch.layout.team_sum(record.reasons != 0)[running]
        series.sent_bytes[row, on] = batch.layout.team_sum(record.outcome.sent_bytes)[running]
        now = running & converged(cerr, thresholds_deg[present])
        series.ctime[present[now]] = k
        running &= ~now
        if not anywhere(running):
            return series.trimmed(k)
        if batch.keeps and batch.layout.team_sizes[~running].sum() >= LEAVING_SHARE * batch.layout.robots:
            batch.keep(running)
            present, running = present[running], running[running]
    return series


def replies(neighbours: tuple[FloatArray, FloatArray], outcome: Exchange,
            content: FloatArray | None, layout: Layout) -> tuple[Received, Received]:
    """What came back to every robot from its predecessor and successor in a step: their step-start
    ``neighbours`` positions (metres) where the reply came, and the ``content`` every robot's
    replies carry (``(T, N, fields)``, robots on axis 1 as ``layout`` lays them out; None: a
    strategy whose replies carry nothing)."""
    carried = (None, None) if content is None else (layout.predecessor(content), layout.successor(content))
    return (Received(neighbours[0], outcome.fresh_minus, np.zeros(outcome.fresh_minus.shape, dtype=np.int64),
                     carried[0]),
            Received(neighbours[1], outcome.fresh_plus, np.zeros(outcome.fresh_plus.shape, dtype=np.int64),
                     carried[1]))
