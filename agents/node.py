"""The protocol of one robot, free of I/O: each received message becomes a list of messages to send.

Per step the world sends the robot a :class:`~bus.messages.Measurement`. The robot observes
(:meth:`agents.controller.MidpointController.observe`); if it does not poll it answers with its
:class:`~bus.messages.Command` at once. If it polls it sends a :class:`~bus.messages.Request` to each
ring neighbour and sends its command when both :class:`~bus.messages.Reply` messages are in
(2 requests + 2 replies per poll, nothing between polls). Replies describe the neighbour's position
at the *start* of the requested step, so lockstep results do not depend on message timing. A reply
is accepted only from the neighbour asked, with the nonce of the open request.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable

import numpy as np

from agents.controller import MidpointController
from bus.keys import WORLD, robot_name
from bus.messages import SCHEMA, Command, End, Measurement, Message, Point, Reply, Request
from world.scenario import Scenario

Outgoing = list[tuple[str, Message]]  # (destination participant, message)

KEPT_STEPS = 16  # own step-start positions remembered to answer late requests


class RobotNode:
    """Robot ``robot`` of ``scenario`` in run ``run``; ``nonce()`` draws request nonces."""

    def __init__(self, robot: int, scenario: Scenario, run: int, nonce: Callable[[], int] | None = None) -> None:
        if not 0 <= robot < scenario.robots:
            raise ValueError(f"--id {robot}: the team has robots 0..{scenario.robots - 1}")
        self.robot = robot
        self.name = robot_name(robot)
        self.scenario = scenario
        self.run = run
        self.predecessor = (robot - 1) % scenario.robots
        self.successor = (robot + 1) % scenario.robots
        self._nonce = nonce or (lambda: secrets.randbits(32))
        self.controller: MidpointController | None = None
        self.step = 0
        self.position: np.ndarray | None = None
        self.trigger = 0
        self.positions: dict[int, Point] = {}
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
        outgoing = self._answer_buffered()
        if self.controller is None:
            self.controller = MidpointController(self.scenario.region, self.scenario.control, self.position)
        self.trigger = int(self.controller.observe(self.step, self.position, self.centre))
        self.awaiting, self.replies = {}, {}
        if not self.trigger:
            return [*outgoing, self._command()]
        self.polls += 1
        for neighbour in (self.predecessor, self.successor):
            nonce = self._nonce()
            self.awaiting[neighbour] = nonce
            outgoing.append(
                (robot_name(neighbour), Request(SCHEMA, self.run, self.step, self.robot, neighbour, nonce))
            )
        return outgoing

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
        assert self.controller is not None and self.position is not None
        before, after = self.replies[self.predecessor], self.replies[self.successor]
        self.controller.receive(
            before.position,
            after.position,
            predecessor_age=self.step - before.step,
            successor_age=self.step - after.step,
        )
        return [self._command()]

    # ------------------------------------------------------------------ helpers
    @property
    def centre(self) -> np.ndarray:
        """The point the robot steers about: the known target of a stationary scenario."""
        return self.scenario.target

    def _command(self) -> tuple[str, Message]:
        assert self.controller is not None and self.position is not None
        goal = self.controller.goal()
        command = Command(
            SCHEMA,
            self.run,
            step=self.step,
            robot=self.robot,
            goal=(float(goal[0]), float(goal[1])),
            trigger=self.trigger,
            guaranteed_offset=float(self.controller.guaranteed_offset),
            centre=(float(self.centre[0]), float(self.centre[1])),
        )
        return (WORLD, command)

    def _reply(self, request: Request) -> tuple[str, Message]:
        """Answer with the position at the start of the requested step, or the oldest kept if that
        step is forgotten (the reply's ``step`` says which)."""
        step = request.step if request.step in self.positions else min(self.positions)
        reply = Reply(SCHEMA, self.run, step, self.robot, request.sender, request.nonce, self.positions[step])
        return (robot_name(request.sender), reply)

    def _answer_buffered(self) -> Outgoing:
        ready = [request for request in self.buffered if request.step <= self.step]
        self.buffered = [request for request in self.buffered if request.step > self.step]
        return [self._reply(request) for request in ready]
