"""The protocol of one robot, free of I/O: each received message becomes a list of messages to send.

Per step the world sends the robot a :class:`~bus.messages.Measurement` (its exact position and a
range to the target). The robot finds the point it steers about:

* ``known``: the stationary target of the scenario;
* ``decentralized``: its own EKF, updated with its own range;
* ``centralized``: it reports its range to the fusion centre (:class:`~bus.messages.RangeReport`)
  and waits for the centre's :class:`~bus.messages.Estimate` of the step (in realtime only so long:
  then it goes on about the last estimate, :meth:`RobotNode.on_estimate_lost`).

Then it observes (:meth:`agents.controller.MidpointController.observe`). If it does not poll it
sends its :class:`~bus.messages.Command` at once; if it polls it sends a
:class:`~bus.messages.Request` to each ring neighbour and commands when both
:class:`~bus.messages.Reply` messages are in (2 requests + 2 replies per poll, nothing between
polls); a decentralized robot first fuses the neighbours' beliefs by covariance intersection.
Replies describe the neighbour at the *start* of the requested step (its position, and its belief
after that step's update, before any fusion), so lockstep results do not depend on message timing.
A reply is accepted only from the neighbour asked, with the nonce of the open request. With the
``relay`` strategy requests and replies carry the ranges the robot holds
(:class:`~bus.messages.RangeRequest`, :class:`~bus.messages.RangeReply`, :class:`agents.relay.RobotRanges`),
which its filter takes at the start of the next step, and replies carry no belief.
"""

from __future__ import annotations

import random
import secrets
from collections.abc import Callable
from collections.abc import Set as AbstractSet

import numpy as np

from ringtrack.agents.controller import CentreUncertainty
from ringtrack.agents.estimation import Estimator, Told, prior_belief, team_steady_variance
from ringtrack.agents.relay import SNAPSHOT_STEPS, VELOCITY_WINDOW_S, RobotRanges
from ringtrack.agents.strategy import Controller, Received, check_strategy
from ringtrack.bus.keys import FUSION, WORLD, robot_name
from ringtrack.bus.messages import (
    NONCE_BASE,
    SCHEMA,
    BeliefRequest,
    CarryingReply,
    Command,
    Covariance,
    End,
    Estimate,
    Measurement,
    Message,
    Point,
    Push,
    PushCommand,
    RangeReply,
    RangeReport,
    RangeRequest,
    Reply,
    Request,
    carries_content,
    compact,
)
from ringtrack.world.geometry import FloatArray
from ringtrack.world.ring import ring_neighbours
from ringtrack.world.scenario import Scenario

Outgoing = list[tuple[str, Message]]  # (destination participant, message)
Belief = tuple[Point, Covariance]

KEPT_STEPS = SNAPSHOT_STEPS  # own step-start positions (beliefs, ranges held) remembered to answer late requests
# Requests for a step this robot has not reached are kept until it does, if that step is at most
# KEPT_STEPS ahead (any step before the robot's first measurement: one that joins a running team
# cannot know the step yet) and at most BUFFERED_LIMIT are waiting; others are ignored (a flood of
# forged far-future requests cannot grow the robot's memory).
BUFFERED_LIMIT = 4 * KEPT_STEPS
# Answers one participant may draw from this robot per step this robot advances: a neighbour sends
# one request per poll, one probe when unreachable and a duplicate at most; more (a flood of
# well-formed requests in its name) is ignored and counted in ``rate_limited``.
ANSWERS_PER_STEP = 4


def pack_point(vector: FloatArray) -> Point:
    return (float(vector[0]), float(vector[1]))


def pack_covariance(matrix: FloatArray) -> Covariance:
    return (float(matrix[0, 0]), float(matrix[0, 1]), float(matrix[1, 1]))


def unpack_covariance(packed: Covariance) -> FloatArray:
    xx, xy, yy = packed
    return np.array([[xx, xy], [xy, yy]])


class RobotNode:
    """Robot ``robot`` of ``scenario`` in run ``run``; ``nonce()`` draws request nonces."""

    def __init__(self, robot: int, scenario: Scenario, run: int, nonce: Callable[[], int] | None = None) -> None:
        if not 0 <= robot < scenario.robots:
            raise ValueError(f"--id {robot}: the team has robots 0..{scenario.robots - 1}")
        self.robot = robot
        self.name = robot_name(robot)
        self.scenario = scenario
        self.run = run
        self.mode = scenario.estimation.mode
        self.predecessor = (robot - 1) % scenario.robots
        self.successor = (robot + 1) % scenario.robots
        # A nonce ties a reply to its request (anyone who reads the bus reads it in the request), so
        # a generator seeded once from the OS serves as well as a draw from the OS per request, which
        # costs a system call. NONCE_BASE + 31 bits: always 5 bytes on the wire.
        draws = random.Random(secrets.randbits(64))
        self._nonce = nonce or (lambda: NONCE_BASE + draws.getrandbits(31))
        self.strategy = check_strategy(scenario)
        self.controller: Controller | None = None
        self.estimator = (
            Estimator(scenario.estimation, scenario.region, scenario.target) if self.mode == "decentralized" else None
        )
        # The relay strategy: the ranges this robot holds of every robot's (agents.relay).
        self.relay = (RobotRanges(robot, scenario.robots, round(VELOCITY_WINDOW_S / scenario.control.dt))
                      if self.estimator is not None and self.strategy.relays else None)
        self.steady_variance = (team_steady_variance(scenario.estimation, scenario.robots)
                                if self.estimator is not None and self.strategy.reads_uncertainty else None)
        self.centre: FloatArray = scenario.target.copy()
        if self.mode == "centralized":  # until the first estimate (late, in realtime): the centre's prior
            prior, _ = prior_belief(scenario.estimation, scenario.region, scenario.target)
            self.centre = scenario.region.clamp_interior(prior, scenario.estimation.margin)
        self.covariance: Covariance | None = None
        self.waiting_for_estimate = False
        self.estimate_step = 0  # step of the centre's estimate the robot steers about (0: none yet)
        self.step = 0
        self.position: FloatArray | None = None
        self.trigger = 0
        self.ages = (0, 0)  # memory ages (steps) when the robot last decided
        self.positions: dict[int, Point] = {}
        self.distances: dict[int, dict[int, float]] = {}  # step -> neighbour -> metres at its start
        self.beliefs: dict[int, Belief] = {}
        self.carried: dict[int, tuple[float, ...]] = {}  # step -> what the strategy's replies carry
        self.answerable = 0  # the latest step whose state (position, belief, carried) replies describe
        # A listening strategy: (neighbour, step) -> the belief it told this robot in that step, the
        # neighbours whose push of the previous step the world named and that has not come yet, and
        # this step's range until the robot has heard; a pushing one: the belief it last told and
        # the neighbours it pushed to this step.
        self.heard: dict[tuple[int, int], Belief] = {}
        self.expected: set[int] = set()
        self.lost_pushes: set[tuple[int, int]] = set()  # (neighbour, step) of pushes lost before they were awaited
        self.measured: tuple[FloatArray, list[float]] | None = None
        self.last_told: Belief | None = None
        if self.estimator is not None and self.strategy.pushes:
            mean, covariance = self.estimator.belief
            self.last_told = (pack_point(mean), pack_covariance(covariance))
        self.pushed: list[int] = []
        self.pushes_sent = 0
        self.pushes_waited_out = 0  # steps a robot heard without a push it waited for, on a timeout
        self.buffered: list[Request] = []
        self.awaiting: dict[int, int] = {}  # neighbour -> nonce of the open request
        self.replies: dict[int, Reply] = {}
        self.alive: frozenset[int] = frozenset(range(scenario.robots))  # replaced, never changed in place
        self._ring_of: frozenset[int] | None = None  # the live set the ring neighbours were last taken from
        self.in_range: set[int] | None = None
        self.polls = 0
        self.probes = 0
        self.ignored_replies = 0
        self.ignored_requests = 0
        self.rate_limited = 0
        self.answers_left: dict[int, int] = {}  # sender -> answers it may still draw this step
        self.answer_budget = ANSWERS_PER_STEP * KEPT_STEPS  # before the first measurement: requests buffered
        self.finished = False

    # ------------------------------------------------------------------ dispatch
    def handle(self, message: Message) -> Outgoing:
        """React to one validated message addressed to this robot."""
        if isinstance(message, Measurement):
            return self.on_measurement(message)
        if isinstance(message, Request):
            return self.on_request(message)
        if isinstance(message, Reply):
            return self.on_reply(message)
        if isinstance(message, Push):
            return self.on_push(message)
        if isinstance(message, Estimate):
            return self.on_estimate(message)
        if isinstance(message, End):
            self.finished = True
        return []

    def on_measurement(self, measurement: Measurement) -> Outgoing:
        if measurement.robot != self.robot or measurement.step <= self.step:
            return []  # not ours, duplicate or out of date
        self._renew_answer_budget(measurement.step - self.step)
        self.step = measurement.step
        self.in_range = None if measurement.in_range is None else set(measurement.in_range)
        self.position = np.asarray(measurement.position, dtype=float)
        self.positions[self.step] = measurement.position
        self.positions.pop(self.step - KEPT_STEPS, None)
        self.distances[self.step] = dict(measurement.distances)
        self.distances.pop(self.step - KEPT_STEPS, None)
        measured = np.nan if measurement.range is None else measurement.range
        listening = self.strategy.listens and self.estimator is not None
        if self.estimator is not None and self.relay is not None:  # late ranges first, as the engine
            params = self.scenario.estimation
            late = self.relay.take(self.step, self.estimator.centre, params.range_sigma, params.process_noise)
            self.estimator.measure(self.position[None, :], [measured], late)
            self.relay.record(self.step, measurement.position, measurement.range)
            self._keep_belief()
        elif self.estimator is not None and not listening:
            self.estimator.measure(self.position[None, :], [measured])
            self._keep_belief()
        # A reply that describes the step's decision (the strategy's carried content) waits for it.
        if not listening and not self.strategy.reply_fields:
            self.answerable = self.step
        outgoing = self._answer_buffered()
        self.awaiting, self.replies = {}, {}
        if measurement.live is not None:  # the world says who is in the ring from this step on
            self.set_alive(set(measurement.live))
        if listening:  # hear what the neighbours told in the previous step, once the named pushes are in
            self.measured = (self.position[None, :], [measured])
            named = set(getattr(measurement, "pushed_by", ())) & {self.predecessor, self.successor}
            settled = self.heard.keys() | self.lost_pushes  # told, or known lost
            self.expected = {robot for robot in named if (robot, self.step - 1) not in settled}
            for key in [key for key in self.heard if key[1] < self.step - 1]:
                del self.heard[key]
            self.lost_pushes = {key for key in self.lost_pushes if key[1] >= self.step - 1}
            return outgoing if self.expected else [*outgoing, *self._hear()]
        if self.mode == "centralized":
            self.waiting_for_estimate = True
            report = RangeReport(SCHEMA, self.run, self.step, self.robot, measurement.position, measurement.range,
                                 measurement.live)
            return [*outgoing, (FUSION, report)]
        decided = self._decide()
        return [*outgoing, *decided]

    def on_estimate(self, estimate: Estimate) -> Outgoing:
        """Steer about the centre's estimate: at once when it is this step's and the robot waits for
        it; one of a step the robot has left (realtime: a centre that fell behind) is still newer than
        the one it holds, and is adopted for its next decision; an older or repeated one is ignored."""
        if estimate.step <= self.estimate_step or estimate.step > self.step:
            return []
        self.estimate_step = estimate.step
        self.centre = np.asarray(estimate.mean, dtype=float)  # the centre's estimator keeps it inside
        self.covariance = estimate.covariance
        if not self.waiting_for_estimate or estimate.step != self.step:
            return []
        self.waiting_for_estimate = False
        return self._decide()

    def on_estimate_lost(self) -> Outgoing:
        """The centre's estimate of this step will not come in time (realtime): decide about the
        last estimate instead."""
        if not self.waiting_for_estimate:
            return []
        self.waiting_for_estimate = False
        return self._decide()

    def _keep_belief(self) -> None:
        """Remember the step's belief (what replies, requests and pushes of the step carry) and steer by it."""
        assert self.estimator is not None
        mean, covariance = self.estimator.belief
        self.beliefs[self.step] = (pack_point(mean), pack_covariance(covariance))
        self.beliefs.pop(self.step - KEPT_STEPS, None)
        self.centre, self.covariance = self.estimator.centre, self.beliefs[self.step][1]

    def _hear(self) -> Outgoing:
        """A listening robot's estimation step, with the beliefs its neighbours told it in the
        previous step (predecessor first), then its answers and its decision."""
        assert self.estimator is not None and self.measured is not None
        self.expected = set()
        told = [self.heard.get((neighbour, self.step - 1)) if neighbour != self.robot else None
                 for neighbour in (self.predecessor, self.successor)]
        if self.successor == self.predecessor:
            told[1] = None  # one neighbour on both sides tells once
        beliefs = [None if belief is None else (np.asarray(belief[0], dtype=float), unpack_covariance(belief[1]))
                   for belief in told]
        positions, ranges = self.measured
        self.strategy.hear(self.estimator.batch, np.asarray(positions, dtype=float)[None],
                           np.asarray(ranges, dtype=float)[None], Told.by_sides(*beliefs))
        self._keep_belief()
        if not self.strategy.reply_fields:
            self.answerable = self.step
        return [*self._answer_buffered(), *self._decide()]

    def _told(self, sender: int, step: int, belief: Belief) -> None:
        """Keep a belief a ring neighbour told this robot (the first of each step; steps a robot can
        still hear or may reach soon only, so a flood cannot grow the memory)."""
        if self._hearable(sender, step):
            self.heard.setdefault((sender, step), belief)

    def _hearable(self, sender: int, step: int) -> bool:
        """Whether what ``sender`` tells of ``step`` is kept: a ring neighbour, of a step this robot
        can still hear or may reach soon (so a flood cannot grow the memory)."""
        return sender in (self.predecessor, self.successor) and self.step - 1 <= step <= self.step + KEPT_STEPS

    def _relayed(self, sender: int, step: int, known: list[int], ranges: list) -> None:
        """Keep the ranges a ring neighbour's message of ``step`` carried (of a step within
        ``KEPT_STEPS`` of this robot's only, so a flood cannot grow the memory)."""
        if self.relay is not None and sender in (self.predecessor, self.successor) and \
                self.step - KEPT_STEPS <= step <= self.step + KEPT_STEPS:
            self.relay.hear(sender, step, known, ranges)

    def on_push(self, push: Push) -> Outgoing:
        """A neighbour's belief, told unasked: heard in the step after ``push.step``."""
        if push.receiver != self.robot or not self.strategy.listens:
            return []
        self._told(push.sender, push.step, (push.mean, push.covariance))
        return self._push_settled(push.sender, push.step)

    def on_push_lost(self, sender: int, step: int) -> Outgoing:
        """A push will not come (dropped). One lost before the robot waits for it (it has not reached
        the step it hears it at) is remembered as lost, so the robot will not wait for it."""
        if self._hearable(sender, step) and step >= self.step:
            self.lost_pushes.add((sender, step))
        return self._push_settled(sender, step)

    def _push_settled(self, sender: int, step: int) -> Outgoing:
        """A push the robot may wait for came or was lost: hear once none is awaited."""
        if step != self.step - 1 or sender not in self.expected:
            return []
        self.expected.discard(sender)
        return [] if self.expected else self._hear()

    def on_pushes_late(self) -> Outgoing:
        """The pushes the robot waits for will not come in time: hear without them (counted in
        ``pushes_waited_out``; in lockstep every push comes or is known lost, so none is)."""
        if not self.expected:
            return []
        self.pushes_waited_out += 1
        return self._hear()

    def on_request(self, request: Request) -> Outgoing:
        if isinstance(request, RangeRequest):
            self._relayed(request.sender, request.step, request.known, request.ranges)
        if isinstance(request, BeliefRequest) and self.strategy.listens:
            self._told(request.sender, request.step, (request.mean, request.covariance))
        if request.step > self.answerable:  # our state of that step is not known yet
            near = self.step == 0 or request.step <= self.step + KEPT_STEPS
            if near and len(self.buffered) < BUFFERED_LIMIT:
                self.buffered.append(request)
            else:
                self.ignored_requests += 1
            return []
        return self._replies([request])

    def on_reply(self, reply: Reply) -> Outgoing:
        if self.awaiting.get(reply.sender) != reply.nonce:
            self.ignored_replies += 1  # stale, duplicated or forged
            return []
        del self.awaiting[reply.sender]
        self.replies[reply.sender] = reply
        if isinstance(reply, RangeReply):
            self._relayed(reply.sender, reply.step, reply.known, reply.ranges)
        return self._settle()

    def on_lost(self, neighbour: int, nonce: int | None = None) -> Outgoing:
        """The request to ``neighbour`` or its reply will not come (dropped, out of range, the
        neighbour left, or too late): go on without it; that side's memory stays stale. With a
        ``nonce``, only the loss of the answer to the open request counts: a lost late copy of an
        answer to an earlier poll settles nothing."""
        if neighbour not in self.awaiting or nonce not in (None, self.awaiting[neighbour]):
            return []
        del self.awaiting[neighbour]
        return self._settle()

    def set_alive(self, alive: AbstractSet[int]) -> Outgoing:
        """The live robots changed (one crashed or came back): re-form the ring around the gap. A
        neighbour that left while its reply was awaited counts as lost; a side whose neighbour
        changed is forgotten, so the robot polls its new neighbour at its next step."""
        self.alive = frozenset(alive)
        outgoing: Outgoing = []
        for neighbour in [n for n in self.awaiting if n not in self.alive]:
            outgoing += self.on_lost(neighbour)
        if not self.awaiting:
            self._reform_ring()
        return outgoing

    def _reform_ring(self) -> None:
        """Take the neighbours the live set implies, forgetting a side whose neighbour changed (once
        per live set: a robot re-forms after every poll, and the set rarely changes)."""
        if self._ring_of is self.alive:
            return
        self._ring_of = self.alive
        predecessor, successor = ring_neighbours(self.robot, self.alive | {self.robot})
        changed = (predecessor != self.predecessor, successor != self.successor)
        if self.controller is not None and any(changed):
            self.controller.forget(*changed)
        self.predecessor, self.successor = predecessor, successor

    def _settle(self) -> Outgoing:
        """Once no reply is awaited: store what came, fuse beliefs, and command."""
        if self.awaiting:
            return []
        assert self.controller is not None
        before, after = self.replies.get(self.predecessor), self.replies.get(self.successor)
        self.strategy.receive(self.controller, self._received(before, self.controller.predecessor_position),
                              self._received(after, self.controller.successor_position))
        beliefs = [None if reply is None or reply.mean is None or reply.covariance is None
                   else (reply.mean, unpack_covariance(reply.covariance)) for reply in (before, after)]
        if self.estimator is not None and any(belief is not None for belief in beliefs):
            self.estimator.fuse(*beliefs)
            self.centre = self.estimator.centre
            self.covariance = pack_covariance(self.estimator.belief[1])
            self.controller.recentre(self.centre)
        command = [self._command()]
        self._reform_ring()  # a ring change may have arrived during the poll
        return command

    def _received(self, reply: Reply | None, remembered: FloatArray) -> Received:
        """One side's reply as the strategy takes it (the remembered position where none came)."""
        fresh = reply is not None
        fields = self.strategy.reply_fields
        content = None if not fields else np.array(getattr(reply, "carried", None) or (0.0,) * fields)
        return Received(np.asarray(reply.position if reply else remembered, dtype=float), np.bool_(fresh),
                        np.int64(self.step - reply.step if reply else 0), content)

    # ------------------------------------------------------------------ helpers
    def _decide(self) -> Outgoing:
        """Observe the step and either command at once or poll both neighbours."""
        assert self.position is not None
        self.pushed = []
        if self.controller is None:
            self.controller = self.strategy.controller(self.scenario.region, self.scenario.control, self.position)
        if len(self.alive) + (self.robot not in self.alive) < 3:
            self.trigger = 0  # no ring to spread on: hold position until robots come back
            return [self._command(hold=True)]
        reach = (self.reachable(self.predecessor), self.reachable(self.successor))
        uncertainty = (None if self.steady_variance is None or self.estimator is None
                       else CentreUncertainty(self.estimator.belief[1], self.steady_variance))
        self.trigger = int(self.controller.observe(self.step, self.position, self.centre, reach,
                                                   uncertainty=uncertainty))
        self.ages = (int(self.controller.predecessor_age), int(self.controller.successor_age))
        answers: Outgoing = []
        if self.strategy.reply_fields:  # replies describe the robot once it has observed the step
            self.carried[self.step] = tuple(float(v) for v in self.strategy.reply_content(self.controller))
            self.carried.pop(self.step - KEPT_STEPS, None)
        if self.strategy.reply_fields:
            self.answerable = self.step
            answers = self._answer_buffered()
        neighbours = (self.predecessor, self.successor)
        # Every unreachable neighbour gets one request per step: the poll itself or a probe.
        probed = [n for n in neighbours if not self.reachable(n)] if not self.trigger else []
        self.probes += len(probed) + sum(1 for n in neighbours if self.trigger and not self.reachable(n))
        outgoing: Outgoing = [*answers, *(self._request(neighbour) for neighbour in probed)]
        if not self.trigger:
            return [*outgoing, *self._pushes(), self._command()]
        if self.strategy.pushes:
            self.last_told = self.beliefs[self.step]  # the requests tell it
        self.polls += 1
        for neighbour in neighbours:
            request = self._request(neighbour)
            self.awaiting[neighbour] = request[1].nonce
            outgoing.append(request)
        return outgoing

    def _request(self, neighbour: int) -> tuple[str, Request]:
        if self.relay is not None and self.relay.snapshots:
            known, ranges = self.relay.carried(self.step, neighbour, self.relay.told.get(neighbour))
            return robot_name(neighbour), RangeRequest(SCHEMA, self.run, self.step, self.robot, neighbour,
                                                       self._nonce(), known, ranges)
        if self.strategy.listens and self.step in self.beliefs:
            mean, covariance = self.beliefs[self.step]
            return robot_name(neighbour), BeliefRequest(SCHEMA, self.run, self.step, self.robot, neighbour,
                                                        self._nonce(), mean, covariance)
        return robot_name(neighbour), Request(SCHEMA, self.run, self.step, self.robot, neighbour, self._nonce())

    def _pushes(self) -> Outgoing:
        """A robot that does not poll: its belief to each reachable ring neighbour, when the strategy
        wants it pushed (:meth:`agents.strategy.Strategy.wants_push`)."""
        if not self.strategy.pushes or self.last_told is None or self.step not in self.beliefs:
            return []
        mean, covariance = self.beliefs[self.step]
        last_mean, last_covariance = self.last_told
        if not bool(self.strategy.wants_push(np.asarray(mean, dtype=float), np.asarray(last_mean, dtype=float),
                                             unpack_covariance(last_covariance), self.scenario.estimation)):
            return []
        self.last_told = (mean, covariance)
        self.pushed = [n for n in dict.fromkeys((self.predecessor, self.successor)) if n != self.robot
                       and self.reachable(n)]
        self.pushes_sent += len(self.pushed)
        return [(robot_name(n), Push(SCHEMA, self.run, self.step, self.robot, n, mean, covariance))
                for n in self.pushed]

    def distance(self, robot: int, step: int) -> float:
        """Metres to ``robot`` at the start of ``step`` as the world measured them; for a robot
        the world did not name as a ring neighbour that step (the ring was changing), the latest
        distance known, else 0."""
        known = self.distances.get(step, {})
        if robot in known:
            return known[robot]
        latest = [seen[robot] for _, seen in sorted(self.distances.items()) if robot in seen]
        return latest[-1] if latest else 0.0

    def reachable(self, robot: int) -> bool:
        """Whether ``robot`` is within communication range this step (always, without a range)."""
        return self.in_range is None or robot in self.in_range

    def _command(self, hold: bool = False) -> tuple[str, Message]:
        assert self.controller is not None and self.position is not None
        limit = self.scenario.communication_range
        reach = (self.reachable(self.predecessor), self.reachable(self.successor))
        goal = self.position if hold else self.controller.goal(reach, limit)
        offset = float(self.controller.guaranteed_offset) if bool(self.controller.offset_known) else None
        fields = (SCHEMA, self.run, self.step, self.robot, pack_point(goal), self.trigger, offset, self.ages,
                  pack_point(self.centre), self.covariance)
        if self.strategy.pushes:
            return (WORLD, PushCommand(*fields, pushed=list(self.pushed)))
        return (WORLD, Command(*fields))

    def _reply(self, request: Request) -> tuple[str, Message]:
        """Answer with the position (and belief) at the start of the requested step, or the oldest
        kept if that step is forgotten (the reply's ``step`` says which)."""
        step = request.step if request.step in self.positions else min(self.positions)
        mean, covariance = self.beliefs.get(step, (None, None))
        fields = (SCHEMA, self.run, step, self.robot, request.sender, request.nonce, self.positions[step], mean,
                  covariance)
        if self.relay is not None and self.relay.snapshots:
            told = self.relay.told.get(request.sender)
            if isinstance(request, RangeRequest) and len(request.known) == self.scenario.robots:
                told = [max(a, b) for a, b in zip(told or request.known, request.known, strict=True)]
            known, ranges = self.relay.carried(step, request.sender, told)
            return (robot_name(request.sender), RangeReply(*fields[:7], None, None, known, ranges))
        carried = self.carried.get(step)
        if carried is not None and carries_content(carried):
            return (robot_name(request.sender), CarryingReply(*fields, carried=compact(carried)))
        return (robot_name(request.sender), Reply(*fields))

    def _answer_buffered(self) -> Outgoing:
        ready = [request for request in self.buffered if request.step <= self.answerable]
        self.buffered = [request for request in self.buffered if request.step > self.answerable]
        return self._replies(ready)

    def _renew_answer_budget(self, steps: int) -> None:
        """A new step, ``steps`` after the last one: every sender may draw ``ANSWERS_PER_STEP`` answers
        per step advanced (a robot that skipped steps answers the requests buffered for them)."""
        self.answers_left = {}
        self.answer_budget = ANSWERS_PER_STEP * max(1, min(steps, KEPT_STEPS))

    def _replies(self, requests: list[Request]) -> Outgoing:
        """Answer ``requests`` within each sender's budget for this step; count the rest as rate limited."""
        answers: Outgoing = []
        for request in requests:
            left = self.answers_left.get(request.sender, self.answer_budget)
            if left <= 0:
                self.rate_limited += 1
                continue
            self.answers_left[request.sender] = left - 1
            answers.append(self._reply(request))
        return answers
