"""The robot process: one :class:`agents.node.RobotNode` driven by messages from the bus.

It waits until the world, both ring neighbours (and the monitor, when one is expected) are up,
declares itself ready, then reacts to every message; between its polls it sends no
robot-to-robot message at all. It ends on the world's End, on a signal, or when the world goes away.
"""

from __future__ import annotations

from bus.config import BusConfig
from bus.keys import BROADCAST, FUSION, MONITOR, WORLD, Keys, robot_name
from bus.messages import End, Measurement
from bus.participant import Delivery, Interrupt, Participant, Presence
from bus.runtime import Roster, gather_until, joined, next_events
from agents.node import RobotNode
from world.scenario import Scenario


async def run_robot(
    robot: int,
    scenario: Scenario,
    run: int,
    bus: BusConfig,
    expect_monitor: bool = False,
    exit_with_parent: bool = False,
) -> int:
    """Run robot ``robot`` until the run ends; returns the exit code (0 done, 1 world lost, 130 stopped)."""
    node = RobotNode(robot, scenario, run)
    keys = Keys(run)
    async with joined(bus, keys, node.name, scenario.robots, exit_with_parent) as participant:
        participant.listen(keys.inbox(node.name))
        participant.listen(keys.inbox(BROADCAST))
        participant.watch("alive")
        participant.announce("alive")
        needed = {WORLD, robot_name(node.predecessor), robot_name(node.successor)}
        needed |= {MONITOR} if expect_monitor else set()
        needed |= {FUSION} if node.mode == "centralized" else set()
        roster = Roster()
        joined_team, events = await gather_until(participant, roster, lambda: needed <= roster.alive)
        if not joined_team:
            return 130
        participant.announce("ready")
        code = await _serve(participant, node, roster, events)
        participant.send(MONITOR, participant.stats(final=True))
        return code


def _newest_measurement_only(events: list) -> list:
    """Drop measurements superseded by a newer one in the same batch (a robot that fell behind the
    realtime clock acts on the latest state; in lockstep a batch never holds two)."""
    steps = [event.message.step for event in events
             if isinstance(event, Delivery) and isinstance(event.message, Measurement)]
    if len(steps) < 2:
        return events
    newest = max(steps)
    return [event for event in events if not (isinstance(event, Delivery) and isinstance(event.message, Measurement)
                                              and event.message.step < newest)]


async def _serve(participant: Participant, node: RobotNode, roster: Roster, events: list) -> int:
    while True:
        for event in _newest_measurement_only(events):
            if isinstance(event, Delivery):
                for destination, message in node.handle(event.message):
                    participant.send(destination, message)
                if isinstance(event.message, End):
                    return 0
            elif isinstance(event, Interrupt):
                return 130
            elif isinstance(event, Presence):
                roster.update(event)
        if roster.gone_for_good(WORLD):
            return 1  # the world went away without ending the run
        events = await next_events(participant, roster)
