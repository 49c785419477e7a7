"""Re-admission as a handshake: a robot is in the ring only once its ring neighbours can reach it.

A robot that comes back (restarted, or woken after a freeze longer than the liveliness lease, or
dropped by a lockstep world that waited too long for it) is first told it is outside the ring (a
:class:`~bus.messages.Measurement` whose ``live`` leaves it out). It then holds a ``reach`` token
for every participant it sees alive, and every robot that sees it alive outside its own ring holds
one for it (:mod:`bus.reach`). At the end of a step the world admits each such robot that reaches
the world (and the monitor, the fusion centre when there are), whose two future ring neighbours
reach it and which reaches them; it is placed and in the ring from the next step, whose
measurements give every robot the new live set.
"""

from __future__ import annotations

from ringtrack.bus.keys import robot_index, robot_name
from ringtrack.bus.reach import Reach
from ringtrack.world.ring import ring_neighbours


class Admission:
    """The ``reach`` tokens of the run as (observer, observed) pairs, and who may come back.

    ``needed`` names the participants every robot must reach besides its neighbours (the world, and
    the monitor and fusion centre when the run has them)."""

    def __init__(self, needed: set[str], robots: int) -> None:
        self.needed = frozenset(needed)
        self.robots = robots
        self.reach: set[tuple[str, str]] = set()

    def update(self, event: Reach) -> None:
        (self.reach.add if event.up else self.reach.discard)((event.observer, event.observed))

    def outside(self, ring: set[int], alive: set[str]) -> list[int]:
        """The robots of the team alive (their token in ``alive``) but not in ``ring``, by id."""
        return sorted(robot for name in alive if (robot := robot_index(name)) is not None
                      and robot < self.robots and robot not in ring)

    def missing(self, robot: int, ring: set[int]) -> list[str]:
        """What robot ``robot`` coming back into ``ring`` still lacks, as ``"a -> b"`` (a does not
        reach b yet); empty when it may be admitted."""
        name = robot_name(robot)
        neighbours = sorted({robot_name(other) for other in ring_neighbours(robot, ring | {robot})} - {name})
        wanted = [(name, other) for other in sorted(self.needed) + neighbours]
        wanted += [(other, name) for other in neighbours]
        return [f"{observer} -> {observed}" for observer, observed in wanted if (observer, observed) not in self.reach]

    def admit(self, ring: set[int], alive: set[str]) -> list[int]:
        """The robots to bring back from the next step: each robot alive outside ``ring`` that
        reaches and is reached as :meth:`missing` says, checked in id order, an admitted robot
        counting as in the ring for the next one."""
        ring, admitted = set(ring), []
        for robot in self.outside(ring, alive):
            if not self.missing(robot, ring):
                ring.add(robot)
                admitted.append(robot)
        return admitted
