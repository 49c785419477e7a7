"""The fusion-centre process of centralized estimation.

Every step each robot reports its position and range (:class:`~bus.messages.RangeReport`). Once all
robots of the team have reported for a step, the centre runs one stacked EKF step over their ranges
in robot order (the same :class:`agents.estimation.Estimator` the engine uses) and broadcasts the
:class:`~bus.messages.Estimate`. Its traffic counts as estimation, not robot-to-robot, traffic.
"""

from __future__ import annotations

import numpy as np

from agents.estimation import Estimator
from agents.node import pack_covariance, pack_point
from bus.config import BusConfig
from bus.keys import BROADCAST, FUSION, MONITOR, WORLD, Keys, robot_name
from bus.messages import SCHEMA, End, Estimate, RangeReport
from bus.participant import Delivery, Interrupt, Presence
from bus.runtime import Roster, gather_until, joined, linger, next_events
from world.scenario import Scenario


class FusionCentre:
    """Collects each step's range reports and turns a complete step into an estimate (no I/O)."""

    def __init__(self, scenario: Scenario, run: int) -> None:
        self.scenario = scenario
        self.run = run
        self.estimator = Estimator(scenario.estimation, scenario.region, scenario.target)
        self.reports: dict[int, dict[int, RangeReport]] = {}
        self.last_step = 0

    def on_report(self, report: RangeReport) -> Estimate | None:
        if report.step <= self.last_step:
            return None  # a step already estimated
        reports = self.reports.setdefault(report.step, {})
        reports[report.robot] = report
        if len(reports) < self.scenario.robots:
            return None
        ordered = [reports[robot] for robot in range(self.scenario.robots)]
        positions = np.array([entry.position for entry in ordered])
        ranges = np.array([np.nan if entry.range is None else entry.range for entry in ordered])
        self.estimator.measure(positions, ranges)
        self.last_step = report.step
        for step in [step for step in self.reports if step <= report.step]:
            del self.reports[step]
        mean, covariance = self.estimator.belief
        return Estimate(SCHEMA, self.run, report.step, pack_point(mean), pack_covariance(covariance))


async def run_fusion(
    scenario: Scenario, run: int, bus: BusConfig, expect_monitor: bool = False, exit_with_parent: bool = False
) -> int:
    """Serve the run's centralized estimate; returns the exit code (0 done, 1 world lost, 130 stopped)."""
    keys = Keys(run)
    centre = FusionCentre(scenario, run)
    async with joined(bus, keys, FUSION, scenario.robots, exit_with_parent) as participant:
        participant.listen(keys.inbox(FUSION))
        participant.listen(keys.inbox(BROADCAST))
        participant.watch("alive")
        participant.announce("alive")
        needed = {WORLD} | {robot_name(i) for i in range(scenario.robots)} | ({MONITOR} if expect_monitor else set())
        roster = Roster()
        started, events = await gather_until(participant, roster, lambda: needed <= roster.alive)
        if not started:
            return 130
        participant.announce("ready")
        code = None
        while code is None:
            for event in events:
                if isinstance(event, Delivery) and isinstance(event.message, RangeReport):
                    estimate = centre.on_report(event.message)
                    if estimate is not None:
                        participant.send(BROADCAST, estimate)
                elif isinstance(event, Delivery) and isinstance(event.message, End):
                    code = 0
                elif isinstance(event, Interrupt):
                    code = 130
                elif isinstance(event, Presence):
                    roster.update(event)
            if code is None and roster.gone_for_good(WORLD):
                code = 1
            if code is None:
                events = await next_events(participant, roster)
        participant.send(MONITOR, participant.stats(final=True))
        if expect_monitor and code != 130:
            await linger(participant, roster, {MONITOR})
        return code
