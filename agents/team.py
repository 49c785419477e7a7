"""A lockstep team of :class:`agents.node.RobotNode` protocols and the world's true state in one
process, with no bus: every message a node sends is handed straight to its destination.

It runs the same per-robot code as the robot processes (one node per robot, one message at a time),
so its cost per step is what the emulator's robots and world compute per step without moving a
single message: the floor under a lockstep step of the emulator (``ringtrack bench suite`` reports
it in neighbour round trips). It also checks the protocol in any delivery order against the engine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ringtrack.agents.node import Outgoing, RobotNode
from ringtrack.agents.strategy import check_strategy
from ringtrack.bus.keys import WORLD, robot_index
from ringtrack.bus.messages import Command
from ringtrack.world.geometry import FloatArray, angle_of
from ringtrack.world.scenario import Scenario
from ringtrack.world.state import WorldState

# Which queued message is delivered next, given how many are queued: ``first`` is FIFO.
Pick = Callable[[int], int]


def first(queued: int) -> int:
    return 0


@dataclass
class TeamRun:
    """What a run of :func:`run_team` did: ``triggers[step - 1, robot]`` (the robot's trigger mask
    of that step), ``angles[step - 1, robot]`` (radians, CCW, seen from the scenario's target, at the
    start of the step) and how many messages were delivered."""

    triggers: NDArray[np.int64]
    angles: FloatArray
    messages: int


def run_team(scenario: Scenario, steps: int, run: int, pick: Pick = first) -> TeamRun:
    """Run ``steps`` lockstep steps of the whole team of ``scenario`` (its own seed) in this process:
    each step the world's measurements go out, every message is delivered (in the order ``pick``
    chooses) until every robot commanded, and the world advances."""
    world = WorldState(scenario, scenario.seed, run, steps, check_strategy(scenario).cerr)
    nodes = [RobotNode(robot, scenario, run) for robot in range(scenario.robots)]
    triggers = np.zeros((steps, scenario.robots), dtype=np.int64)
    angles = np.zeros((steps, scenario.robots))
    messages = 0
    for step in range(steps):
        angles[step] = angle_of(world.positions, scenario.target)
        queue: Outgoing = [(nodes[robot].name, world.measurement(robot)) for robot in range(scenario.robots)]
        while queue:
            destination, message = queue.pop(pick(len(queue)))
            messages += 1
            if destination == WORLD:
                assert isinstance(message, Command)
                if world.possible(message):
                    world.accept(message)
                continue
            robot = robot_index(destination)
            assert robot is not None
            queue.extend(nodes[robot].handle(message))
        triggers[step] = [node.trigger for node in nodes]
        world.advance()
    return TeamRun(triggers, angles, messages)
