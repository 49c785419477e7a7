"""The fusion-centre process of centralized estimation.

Every step each robot reports its position and range (:class:`~bus.messages.RangeReport`). Once
every robot expected for a step has reported, the centre runs one stacked EKF step over the step's
ranges in robot order (the same :class:`agents.estimation.Estimator` the engine uses) and broadcasts
the :class:`~bus.messages.Estimate`. Its traffic counts as estimation, not robot-to-robot, traffic.

The centre expects the robots that are alive, as the world does: the team starts whole, a robot
whose process goes away (its liveliness token is withdrawn) is no longer waited for, so a step it
left pending is estimated from the reports of the others, and a robot that comes back is expected
from the step the world brings it back at, which every report of that step names (``live``). With
nobody leaving, every step waits for the whole team, so a lockstep run equals the engine.
"""

from __future__ import annotations

import numpy as np

from ringtrack.agents.estimation import Estimator
from ringtrack.agents.node import pack_covariance, pack_point
from ringtrack.bus.config import BusConfig
from ringtrack.bus.keys import BROADCAST, FUSION, MONITOR, WORLD, Keys, participants, robot_index
from ringtrack.bus.messages import SCHEMA, End, Estimate, RangeReport
from ringtrack.bus.participant import Delivery, Interrupt, Participant, Presence
from ringtrack.bus.runtime import STOPPED, Interrupts, Role, Roster, next_events, perform
from ringtrack.world.scenario import Scenario


class FusionCentre:
    """Collects each step's range reports and turns a complete step into an estimate (no I/O)."""

    def __init__(self, scenario: Scenario, run: int) -> None:
        self.scenario = scenario
        self.run = run
        self.estimator = Estimator(scenario.estimation, scenario.region, scenario.target)
        self.reports: dict[int, dict[int, RangeReport]] = {}  # step -> robot -> report
        self.expected: dict[int, int] = dict.fromkeys(range(scenario.robots), 1)  # robot -> first step
        self.last_step = 0

    def on_report(self, report: RangeReport) -> list[Estimate]:
        """Take a robot's report; returns the estimates of the steps it completes (at most one)."""
        if report.step <= self.last_step:
            return []  # a step already estimated
        if report.live is not None:  # the world says who is in the ring from this step on
            for robot in set(self.expected) - set(report.live):
                del self.expected[robot]  # one the world stopped waiting for (its lease has not run out)
            for robot in report.live:  # one the world brought back at this step
                self.expected.setdefault(robot, report.step)
        self.reports.setdefault(report.step, {})[report.robot] = report
        return self._complete_steps()

    def on_leave(self, robot: int) -> list[Estimate]:
        """Robot ``robot`` has gone: stop waiting for it; returns the estimates of the pending steps
        that are now complete, oldest first."""
        self.expected.pop(robot, None)
        return self._complete_steps()

    def _complete_steps(self) -> list[Estimate]:
        """Estimate, in order, every pending step that every robot expected for it has reported;
        estimating a step gives up the older ones still incomplete."""
        return [self._estimate(step) for step in sorted(self.reports) if self._complete(step)]

    def _complete(self, step: int) -> bool:
        reported = self.reports[step]
        return all(robot in reported for robot, first in self.expected.items() if first <= step)

    def _estimate(self, step: int) -> Estimate:
        """One filter step over the reports of ``step`` in robot order."""
        reports = self.reports[step]
        ordered = [reports[robot] for robot in sorted(reports)]
        positions = np.array([entry.position for entry in ordered])
        ranges = np.array([np.nan if entry.range is None else entry.range for entry in ordered])
        self.estimator.measure(positions, ranges)
        self.last_step = step
        for done in [pending for pending in self.reports if pending <= step]:
            del self.reports[done]
        mean, covariance = self.estimator.belief
        return Estimate(SCHEMA, self.run, step, pack_point(mean), pack_covariance(covariance))


async def run_fusion(
    scenario: Scenario, run: int, bus: BusConfig, expect_monitor: bool = False, exit_with_parent: bool = False
) -> int:
    """Serve the run's centralized estimate; returns the exit code (0 done, 1 world lost, 130 stopped)."""
    keys = Keys(run)
    centre = FusionCentre(scenario, run)

    async def main(participant: Participant, roster: Roster, events: list) -> int:
        code = None
        while code is None:
            for event in events:
                estimates: list[Estimate] = []
                if isinstance(event, Delivery) and isinstance(event.message, RangeReport):
                    estimates = centre.on_report(event.message)
                elif isinstance(event, Delivery) and isinstance(event.message, End):
                    code = 0
                elif isinstance(event, Interrupt):
                    code = STOPPED
                elif isinstance(event, Presence):
                    roster.update(event)
                    estimates = _on_presence(centre, event)
                for estimate in estimates:
                    participant.send(BROADCAST, estimate)
            if code is None and roster.gone_for_good(WORLD):
                code = 1
            if code is None:
                events = await next_events(participant, roster)
        return code

    role = Role(
        name=FUSION,
        needed=participants(range(scenario.robots), centralized=False, monitor=expect_monitor),
        main=main,
        listen=(keys.inbox(FUSION), keys.inbox(BROADCAST)),
        linger_for=lambda code: {MONITOR} if expect_monitor and code != STOPPED else set(),
    )
    return await perform(role, bus, keys, scenario.robots, Interrupts(exit_with_parent))


def _on_presence(centre: FusionCentre, presence: Presence) -> list[Estimate]:
    """A robot leaves when its ``alive`` token goes (the world's rule, :func:`world.process.run_world`)."""
    robot = robot_index(presence.name)
    if robot is None or presence.kind != "alive" or presence.up:
        return []
    return centre.on_leave(robot)
