"""How a batch of the engine lays out the robots of its teams: robots on axis 1 of every per-robot
array, each team a ring (:mod:`world.ring`: robot ``i + 1`` is the counter-clockwise successor of
``i``, the last robot's successor is the first).

A *uniform* batch holds T teams of N robots each: per-robot arrays of shape ``(T, N, ...)``. A
*ragged* one holds teams of several sizes one after another on a single row: ``(1, R, ...)``, R the
robots of all its teams, teams in the order given (those of one size kept together make fewer
:attr:`Layout.groups`). Per-team values are ``(T, ...)`` either way. The ring arithmetic of a
ragged batch is that of the teams' own rings, and every value summed over a team's robots is
summed exactly as a uniform batch of that team's size sums it (the same reduction of the same
numbers in the same order), so a team's run is the same in either layout, to the last bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ringtrack.world.ring import cyclic_index


@dataclass(frozen=True, eq=False)
class Layout:
    """The teams of a batch, ``sizes`` (robots per team, in order), ragged or uniform (see the
    module docstring). ``groups`` are the runs of teams of equal size along the robot axis:
    ``(first robot, teams, robots per team)``."""

    sizes: tuple[int, ...]
    ragged: bool
    cache: dict[Any, Any] = field(default_factory=dict, repr=False)  # what users work out once per layout

    @classmethod
    def uniform(cls, trials: int, robots: int) -> Layout:
        """``trials`` teams of ``robots`` robots, arrays ``(T, N, ...)``."""
        return cls((robots,) * trials, False)

    @classmethod
    def of_teams(cls, sizes: Sequence[int]) -> Layout:
        """Teams of the given sizes one after another, arrays ``(1, R, ...)``."""
        if not sizes or min(sizes) < 1:
            raise ValueError(f"team sizes {list(sizes)}: give at least one team of at least one robot")
        return cls(tuple(int(size) for size in sizes), True)

    @cached_property
    def team_sizes(self) -> NDArray[np.int64]:
        """:attr:`sizes` as an array."""
        return np.asarray(self.sizes, dtype=np.int64)

    @property
    def trials(self) -> int:
        """Teams in the batch."""
        return len(self.sizes)

    @cached_property
    def robots(self) -> int:
        """Robots on axis 1: N (uniform) or R, those of every team (ragged)."""
        return sum(self.sizes) if self.ragged else self.sizes[0]

    @cached_property
    def shape(self) -> tuple[int, int]:
        """The first two axes of a per-robot array."""
        return (1, self.robots) if self.ragged else (self.trials, self.robots)

    @cached_property
    def groups(self) -> tuple[tuple[int, int, int], ...]:
        """``(first robot, teams, robots per team)`` of each run of teams of one size."""
        runs: list[tuple[int, int, int]] = []
        first = 0
        for size in self.sizes:
            if runs and runs[-1][2] == size:
                start, teams, _ = runs[-1]
                runs[-1] = (start, teams + 1, size)
            else:
                runs.append((first, 1, size))
            first += size
        return tuple(runs)

    @cached_property
    def _local(self) -> NDArray[np.intp]:
        """Each robot's id in its team, along axis 1."""
        if not self.ragged:
            return np.arange(self.robots)
        return np.concatenate([np.tile(np.arange(size), teams) for _, teams, size in self.groups])

    @cached_property
    def _indices(self) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """The index along axis 1 of each robot's predecessor and successor."""
        if not self.ragged:
            return cyclic_index(self.robots, -1), cyclic_index(self.robots, 1)
        size = np.repeat(np.asarray(self.sizes), self.sizes)
        first = np.arange(self.robots) - self._local
        predecessor, successor = first + (self._local - 1) % size, first + (self._local + 1) % size
        for index in (predecessor, successor):
            index.setflags(write=False)
        return predecessor, successor

    @cached_property
    def _side_index(self) -> NDArray[np.intp]:
        """The index along axis 1 of each robot's (predecessor, successor), shape (N, 2)."""
        return np.stack(self._indices, axis=-1)

    def sides(self, values: NDArray) -> NDArray:
        """What each robot's predecessor and successor hold of ``values`` (robots on axis 1), the
        sides on a new axis 2: ``(T, N, 2, ...)`` of ``(T, N, ...)``."""
        return values.take(self._side_index, axis=1)

    def predecessor(self, values: NDArray, axis: int = 1) -> NDArray:
        """What each robot's predecessor holds of ``values`` (robots on ``axis``)."""
        return values.take(self._indices[0], axis=axis)

    def successor(self, values: NDArray, axis: int = 1) -> NDArray:
        """What each robot's successor holds of ``values`` (robots on ``axis``)."""
        return values.take(self._indices[1], axis=axis)

    @cached_property
    def ids(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Each robot's id in its team and its (predecessor, successor) ids, shapes ``(1, N, 1)`` and
        ``(1, N, 2)`` (ragged: N is R), read-only."""
        local = self._local.astype(np.int64)
        robot, neighbour = local[None, :, None], local[self._side_index][None]
        for values in (robot, neighbour):
            values.setflags(write=False)
        return robot, neighbour

    def per_robot(self, values: NDArray) -> NDArray:
        """Per-team ``values`` (T, ...) as per-robot ones that broadcast against ``(*shape, ...)``:
        ``(T, 1, ...)`` uniform, each team's value repeated for its robots ``(1, R, ...)`` ragged."""
        return values[:, None] if not self.ragged else self.spread(values)

    def spread(self, values: NDArray) -> NDArray:
        """Per-team ``values`` (T, ...) as a per-robot array ``(*shape, ...)``, each team's value
        for each of its robots."""
        if not self.ragged:
            return np.repeat(values[:, None], self.robots, axis=1)
        return np.repeat(values, self.sizes, axis=0)[None]

    def team_sum(self, values: NDArray) -> NDArray:
        """Each team's sum over its robots of per-robot ``values`` (robots on axis 1), ``(T, ...)``:
        a uniform batch's reduction over axis 1; a ragged one's, for floats, the same reduction of
        each group's ``(teams, size, ...)`` view (so each team's sum has the bits of a uniform
        batch's), for whole numbers one cut of the axis at each team's first robot."""
        if not self.ragged:
            return np.add.reduce(values, axis=1)
        if not np.issubdtype(values.dtype, np.floating):  # whole numbers (or flags, counted)
            return np.add.reduceat(values, self._firsts, axis=1, dtype=np.int64)[0]
        rest = values.shape[2:]
        return np.concatenate([np.add.reduce(values[0, first:first + teams * size].reshape((teams, size, *rest)),
                                             axis=1) for first, teams, size in self.groups])

    @cached_property
    def _firsts(self) -> NDArray[np.intp]:
        """The index along axis 1 of each team's first robot."""
        return np.concatenate([[0], np.cumsum(self.sizes[:-1])]).astype(np.intp)

    def keep(self, teams: NDArray[np.bool_]) -> tuple[Layout, NDArray[np.intp]]:
        """The ragged layout of the ``teams`` kept (a mask of :attr:`trials`) and the index along
        axis 1 that takes their robots' values out of a per-robot array."""
        if not self.ragged:
            raise ValueError("a uniform batch keeps all its teams; lay them out with Layout.of_teams")
        kept = tuple(size for size, keep in zip(self.sizes, teams, strict=True) if keep)
        return Layout.of_teams(kept), np.flatnonzero(np.repeat(teams, self.sizes))
