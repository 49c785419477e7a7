"""The protocol of one robot, free of I/O: each received message becomes a list of messages to send.

Per step the world sends the robot a :class:`~bus.messages.Measurement` (its exact position and a
range to the target). The robot finds the point it steers about:

* ``known``: the stationary target of the scenario;
* ``decentralized``: its own EKF, updated with its own range;
* ``centralized``: it reports its range to the fusion centre (:class:`~bus.messages.RangeReport`)
  and waits for the centre's :class:`~bus.messages.Estimate` of the step.

Then it observes (:meth:`agents.controller.MidpointController.observe`). If it does not poll it
sends its :class:`~bus.messages.Command` at once; if it polls it sends a
:class:`~bus.messages.Request` to each ring neighbour and commands when both
:class:`~bus.messages.Reply` messages are in (2 requests + 2 replies per poll, nothing between
polls); a decentralized robot first fuses the neighbours' beliefs by covariance intersection.
Replies describe the neighbour at the *start* of the requested step (its position, and its belief
after that step's update, before any fusion), so lockstep results do not depend on message timing.
A reply is accepted only from the neighbour asked, with the nonce of the open request.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable

import numpy as np

from agents.controller import MidpointController
from agents.estimation import Estimator
from bus.keys import FUSION, WORLD, robot_name
from bus.messages import (
    SCHEMA,
    Command,
    Covariance,
    End,
    Estimate,
    Measurement,
    Message,
    Point,
    RangeReport,
    Reply,
    Request,
)
from world.geometry import FloatArray
from world.scenario import Scenario

Outgoing = list[tuple[str, Message]]  # (destination participant, message)
Belief = tuple[Point, Covariance]

KEPT_STEPS = 16  # own step-start positions (and beliefs) remembered to answer late requests


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
        self._nonce = nonce or (lambda: secrets.randbits(32))
        self.controller: MidpointController | None = None
        self.estimator = (
            Estimator(scenario.estimation, scenario.region, scenario.target) if self.mode == "decentralized" else None
        )
        self.centre: FloatArray = scenario.target.copy()
        self.covariance: Covariance | None = None
        self.waiting_for_estimate = False
        self.step = 0
        self.position: FloatArray | None = None
        self.trigger = 0
        self.ages = (0, 0)  # memory ages (steps) when the robot last decided
        self.positions: dict[int, Point] = {}
        self.beliefs: dict[int, Belief] = {}
        self.buffered: list[Request] = []
        self.awaiting: dict[int, int] = {}  # neighbour -> nonce of the open request
        self.replies: dict[int, Reply] = {}
        self.polls = 0
        self.ignored_replies = 0
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
        if isinstance(message, Estimate):
            return self.on_estimate(message)
        if isinstance(message, End):
            self.finished = True
        return []

    def on_measurement(self, measurement: Measurement) -> Outgoing:
        if measurement.robot != self.robot or measurement.step <= self.step:
            return []  # not ours, duplicate or out of date
        self.step = measurement.step
        self.position = np.asarray(measurement.position, dtype=float)
        self.positions[self.step] = measurement.position
        self.positions.pop(self.step - KEPT_STEPS, None)
        measured = np.nan if measurement.range is None else measurement.range
        if self.estimator is not None:
            self.estimator.measure(self.position[None, :], [measured])
            mean, covariance = self.estimator.belief
            self.beliefs[self.step] = (pack_point(mean), pack_covariance(covariance))
            self.beliefs.pop(self.step - KEPT_STEPS, None)
            self.centre, self.covariance = self.estimator.centre, self.beliefs[self.step][1]
        outgoing = self._answer_buffered()
        self.awaiting, self.replies = {}, {}
        if self.mode == "centralized":
            self.waiting_for_estimate = True
            report = RangeReport(SCHEMA, self.run, self.step, self.robot, measurement.position, measurement.range)
            return [*outgoing, (FUSION, report)]
        return [*outgoing, *self._decide()]

    def on_estimate(self, estimate: Estimate) -> Outgoing:
        if not self.waiting_for_estimate or estimate.step != self.step:
            return []  # an estimate of a step this robot has left
        self.waiting_for_estimate = False
        margin = self.scenario.estimation.clamp_margin
        self.centre = self.scenario.region.clamp_interior(np.asarray(estimate.mean), margin)
        self.covariance = estimate.covariance
        return self._decide()

    def on_request(self, request: Request) -> Outgoing:
        if request.step > self.step:
            self.buffered.append(request)  # our measurement of that step has not arrived yet
            return []
        return [self._reply(request)]

    def on_reply(self, reply: Reply) -> Outgoing:
        if self.awaiting.get(reply.sender) != reply.nonce:
            self.ignored_replies += 1  # stale, duplicated or forged
            return []
        del self.awaiting[reply.sender]
        self.replies[reply.sender] = reply
        if self.awaiting:
            return []
        assert self.controller is not None
        before, after = self.replies[self.predecessor], self.replies[self.successor]
        self.controller.receive(
            before.position,
            after.position,
            predecessor_age=self.step - before.step,
            successor_age=self.step - after.step,
        )
        beliefs = [(reply.mean, unpack_covariance(reply.covariance)) for reply in (before, after)
                   if reply.mean is not None and reply.covariance is not None]
        if self.estimator is not None and beliefs:
            self.estimator.fuse(beliefs)
            self.centre = self.estimator.centre
            self.covariance = pack_covariance(self.estimator.belief[1])
            self.controller.recentre(self.centre)
        return [self._command()]

    # ------------------------------------------------------------------ helpers
    def _decide(self) -> Outgoing:
        """Observe the step and either command at once or poll both neighbours."""
        assert self.position is not None
        if self.controller is None:
            self.controller = MidpointController(self.scenario.region, self.scenario.control, self.position)
        self.trigger = int(self.controller.observe(self.step, self.position, self.centre))
        self.ages = (int(self.controller.predecessor_age), int(self.controller.successor_age))
        if not self.trigger:
            return [self._command()]
        self.polls += 1
        outgoing: Outgoing = []
        for neighbour in (self.predecessor, self.successor):
            nonce = self._nonce()
            self.awaiting[neighbour] = nonce
            outgoing.append(
                (robot_name(neighbour), Request(SCHEMA, self.run, self.step, self.robot, neighbour, nonce))
            )
        return outgoing

    def _command(self) -> tuple[str, Message]:
        assert self.controller is not None
        command = Command(
            SCHEMA,
            self.run,
            step=self.step,
            robot=self.robot,
            goal=pack_point(self.controller.goal()),
            trigger=self.trigger,
            guaranteed_offset=float(self.controller.guaranteed_offset),
            ages=self.ages,
            centre=pack_point(self.centre),
            covariance=self.covariance,
        )
        return (WORLD, command)

    def _reply(self, request: Request) -> tuple[str, Message]:
        """Answer with the position (and belief) at the start of the requested step, or the oldest
        kept if that step is forgotten (the reply's ``step`` says which)."""
        step = request.step if request.step in self.positions else min(self.positions)
        mean, covariance = self.beliefs.get(step, (None, None))
        reply = Reply(SCHEMA, self.run, step, self.robot, request.sender, request.nonce, self.positions[step],
                      mean, covariance)
        return (robot_name(request.sender), reply)

    def _answer_buffered(self) -> Outgoing:
        ready = [request for request in self.buffered if request.step <= self.step]
        self.buffered = [request for request in self.buffered if request.step > self.step]
        return [self._reply(request) for request in ready]
