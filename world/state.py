"""The world's ground truth between steps: robot positions, the target, and the motion step.

Shared by the world process and (through the same motion call) the in-process engine. Units:
metres, seconds; ``step`` is 1-based and ``time = (step - 1) * dt``.
"""

from __future__ import annotations

import numpy as np

from ringtrack.bus.messages import SCHEMA, Command, Measurement, PushCommand, PushMeasurement, Tick
from ringtrack.world.geometry import FloatArray
from ringtrack.world.metrics import CerrSource, converged, memory_cerr, strategy_cerr, true_cerr
from ringtrack.world.ranges import link_distance
from ringtrack.world.ring import neighbours_in_ring, successor_values
from ringtrack.world.scenario import Scenario
from ringtrack.world.sensing import RangeSensor


def motion_step(scenario: Scenario, positions: FloatArray, goals: FloatArray) -> FloatArray:
    """One step of the world's motion: every robot moves along the boundary towards its goal (both
    metres, robots on axis -2), at most ``v_max * dt`` metres when the scenario caps the speed."""
    max_move = None if scenario.v_max is None else scenario.v_max * scenario.control.dt
    return scenario.region.move_along(positions, goals, max_move)


class WorldState:
    """Positions of ``scenario.robots`` robots started from ``seed``, the target on its path for
    ``steps`` steps, the ranges measured at the start of the current step, and the goals commanded
    for it. ``cerr`` is the Cerr that decides convergence, as the scenario's strategy says
    (:attr:`agents.strategy.Strategy.cerr`; the world does not know strategies)."""

    def __init__(self, scenario: Scenario, seed: int, run: int, steps: int, cerr: CerrSource = "memory") -> None:
        self.scenario = scenario
        self.cerr_source = cerr
        self.run = run
        self.positions: FloatArray = scenario.start_positions(seed)
        self.path = scenario.target_path(seed, steps)
        self.target: FloatArray = self.path[0]
        sensing = scenario.spec.sensing
        self.sensor = RangeSensor(sensing.range_sigma, sensing.range, seed)
        self.ranges: FloatArray = self.sensor.measure(self.positions, self.target)
        self.live: set[int] = set(range(scenario.robots))
        self.ring: tuple[int, ...] = tuple(range(scenario.robots))  # the live ids in ascending order
        self.rejoining: set[int] = set()  # back from the next step on
        self.returned: set[int] = set()  # came back at the start of this step: everyone hears of it
        self.left: set[int] = set()  # left the ring during this step
        self.shrunk = False  # robots left during the last step: everyone hears of it
        self.goals: FloatArray = self.positions.copy()
        self.offsets: FloatArray = np.full(scenario.robots, np.nan)  # gV - theta reported for this step, rad
        self.commanded: set[int] = set()
        # Robot -> the robots that pushed it their belief in this step, and in the previous one.
        self.pushes: dict[int, set[int]] = {}
        self.pushed_last: dict[int, set[int]] = {}
        self.step = 1
        self.boundary_tolerance = 1e-6 * scenario.region.outer_diameter  # metres
        # ring_links' cache: the step and the ring it was computed for, and the links
        self._ring_links: tuple[int, tuple[int, ...], dict[int, list[tuple[int, float]]]] | None = None

    @property
    def time(self) -> float:
        return (self.step - 1) * self.scenario.control.dt

    def measurement(self, robot: int) -> Measurement:
        """Robot ``robot``'s exact position and its measured range to the target (None beyond the
        sensing range) at the start of the step, with the live set when the ring changed or the robot
        is not in it (then it is told so: :mod:`world.admission`); a :class:`PushMeasurement` naming
        the robots that pushed it their belief in the previous step when any did."""
        position = self.positions[robot]
        measured = self.ranges[robot]
        fields = (SCHEMA, self.run, self.step, self.time, robot, (float(position[0]), float(position[1])),
                  None if np.isnan(measured) else float(measured), self.in_range(robot),
                  list(self.ring) if self.returned or self.shrunk or robot not in self.live else None,
                  self.neighbour_distances(robot))
        pushed_by = self.pushed_last.get(robot)
        return PushMeasurement(*fields, sorted(pushed_by)) if pushed_by else Measurement(*fields)

    def neighbour_distances(self, robot: int) -> list[tuple[int, float]]:
        """``(neighbour, metres)`` of the links from ``robot`` to its live ring neighbours, in
        ascending id order. A robot of the ring reads them from :meth:`ring_links`, computed once for
        the current positions and ring (the world asks for every robot each step)."""
        links = self.ring_links()
        if robot in links:
            return links[robot]
        neighbours = sorted(set(neighbours_in_ring(robot, self.ring)) - {robot})
        return [(other, float(link_distance(self.positions[robot], self.positions[other]))) for other in neighbours]

    def ring_links(self) -> dict[int, list[tuple[int, float]]]:
        """Each live robot's ``(neighbour, metres)`` links to its ring neighbours, ascending by id:
        every link's length computed in one :func:`world.ranges.link_distance` call over the ring
        (elementwise, so the same bits as one link at a time), kept for the rest of the step while the
        ring stays (positions change only between steps)."""
        if self._ring_links is not None and self._ring_links[:2] == (self.step, self.ring):
            return self._ring_links[2]
        ring = self.ring
        links: dict[int, list[tuple[int, float]]] = {}
        if len(ring) == 1:
            links[ring[0]] = []
        elif ring:
            members = np.asarray(ring)
            lengths = link_distance(self.positions[members], self.positions[successor_values(members)]).tolist()
            for index, robot in enumerate(ring):  # link ``index`` joins ring[index] to its successor
                predecessor, successor = ring[index - 1], ring[(index + 1) % len(ring)]
                around = {predecessor: lengths[index - 1], successor: lengths[index]}
                links[robot] = sorted(around.items())
        self._ring_links = (self.step, ring, links)
        return links

    def rejoin(self, robot: int) -> None:
        """Bring a restarted robot back into the ring from the next step on (it has no measurement
        of the current one, so a lockstep world must not wait for its command)."""
        self.rejoining.add(robot)

    def leave(self, robot: int) -> None:
        """A robot's process went away (or stopped answering): it stays where it is, out of the ring."""
        if robot in self.live:
            self.left.add(robot)
        self.live.discard(robot)
        self.ring = tuple(sorted(self.live))
        self.rejoining.discard(robot)

    def _place(self, robot: int) -> None:
        """Put a rejoining robot midway along the boundary between its live ring neighbours (as an
        operator would put it back): where it stopped may no longer lie between them, since they
        re-spread while it was gone, and the ring is ordered by id."""
        predecessor, successor = neighbours_in_ring(robot, self.ring)
        if predecessor != successor:
            region = self.scenario.region
            start, end = region.arc_length(self.positions[predecessor]), region.arc_length(self.positions[successor])
            middle = start + np.mod(end - start, region.perimeter) / 2.0
            self.positions[robot] = self.goals[robot] = region.point_at(middle)
        self.live.add(robot)
        self.ring = tuple(sorted(self.live))

    def in_range(self, robot: int) -> list[int] | None:
        """The other live robots within the communication range of ``robot`` (None: unlimited)."""
        limit = self.scenario.communication_range
        if limit is None:
            return None
        distances = link_distance(self.positions[robot], self.positions)
        return [other for other in self.ring if other != robot and distances[other] <= limit]

    def tick(self, live: list[int]) -> Tick:
        """The true state at the start of the step, for the monitor."""
        return Tick(
            SCHEMA,
            self.run,
            self.step,
            self.time,
            [(float(x), float(y)) for x, y in self.positions],
            (float(self.target[0]), float(self.target[1])),
            live,
        )

    def possible(self, command: Command) -> bool:
        """Whether the command's goal lies on the boundary (every robot's does; a forged command's
        may not, and the world never moves a robot off the boundary)."""
        return bool(self.scenario.region.on_boundary(command.goal, self.boundary_tolerance))

    def accept(self, command: Command) -> bool:
        """Take a robot's goal (in realtime also one computed for an earlier step); its offset and,
        in lockstep, its command count only for the current step."""
        if command.step > self.step:
            return False
        self.goals[command.robot] = command.goal
        if command.step == self.step:
            offset = command.guaranteed_offset
            self.offsets[command.robot] = np.nan if offset is None else offset
            self.commanded.add(command.robot)
            if isinstance(command, PushCommand):
                for receiver in command.pushed:
                    self.pushes.setdefault(receiver, set()).add(command.robot)
        return True

    def converged(self) -> bool:
        """Whether the current step counts as converged (:func:`world.metrics.converged`) by the
        paper's Cerr: from the offsets the live robots reported for this step (self-triggered; a
        live robot that has not reported leaves it unknown) or the true positions (constant)."""
        live = np.zeros(self.scenario.robots, dtype=bool)
        live[list(self.ring)] = True
        cerr = strategy_cerr(self.cerr_source, memory_cerr(self.offsets, live),
                             true_cerr(self.positions, self.target))
        return bool(converged(cerr, np.rad2deg(self.scenario.threshold)))

    def advance(self) -> None:
        """Move every robot towards its latest goal along the boundary (capped by v_max), bring back
        the robots that rejoined, and start the next step."""
        self.positions = motion_step(self.scenario, self.positions, self.goals)
        for robot in sorted(self.rejoining):
            self._place(robot)
        self.returned, self.rejoining = self.rejoining & self.live, set()
        self.shrunk, self.left = bool(self.left), set()
        self.commanded.clear()
        self.pushed_last, self.pushes = self.pushes, {}
        self.offsets[:] = np.nan
        self.step += 1
        self.target = self.path[min(self.step, len(self.path)) - 1]
        self.ranges = self.sensor.measure(self.positions, self.target)
