"""Circle arithmetic of a robot ring (docs/algorithms.md section 2).

Robots ``0..N-1`` sit in counter-clockwise (CCW) order; robot ``i+1`` is the CCW successor of ``i``.
Angles are radians. A robot reads its neighbours' angles in its own *local frame*: the successor's
angle is placed in ``[theta, theta + 2 pi)`` and the predecessor's in ``(theta - 2 pi, theta]``, so
"``theta_{i+1} > theta_i > theta_{i-1}``" means strictly positive gaps. Every function broadcasts over
leading axes (robots, trials).
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Sequence
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.geometry import TWO_PI, FloatArray


def wrap(angle: ArrayLike) -> FloatArray:
    """``angle mod 2 pi`` in ``[0, 2 pi)`` (radians). A float's ``%`` is numpy's ``mod`` (the same
    floored remainder, the same bits) without its cost per call."""
    if isinstance(angle, float):
        return angle % TWO_PI
    return np.mod(angle, TWO_PI)


def local_frame(theta: ArrayLike, predecessor: ArrayLike, successor: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Neighbour angles in the frame of a robot at ``theta`` (all radians, any representation).

    Returns ``(m_minus, m_plus)`` with ``m_plus = theta + wrap(successor - theta)`` and
    ``m_minus = theta - wrap(theta - predecessor)``.
    """
    if not isinstance(theta, float):
        theta = np.asarray(theta, dtype=float)
    return theta - wrap(theta - predecessor), theta + wrap(successor - theta)


def midpoint(m_minus: ArrayLike, theta: ArrayLike, m_plus: ArrayLike) -> FloatArray:
    """Midpoint of the robot's Voronoi segment on the circle, ``(m_minus + 2 theta + m_plus) / 4``
    (radians). With remembered rather than current neighbour angles it is the guaranteed midpoint gV."""
    if isinstance(theta, float) and isinstance(m_minus, float) and isinstance(m_plus, float):  # one robot's
        return (m_minus + 2.0 * theta + m_plus) / 4.0
    return (np.asarray(m_minus) + 2.0 * np.asarray(theta) + np.asarray(m_plus)) / 4.0


def successor_values(values: ArrayLike, axis: int = -1) -> NDArray:
    """What each robot's CCW successor holds of ``values`` (robots along ``axis``): ``np.roll(values,
    -1, axis)``, as an indexed take, which costs a fifth of ``np.roll`` on a team's small arrays."""
    values = np.asarray(values)
    return values.take(cyclic_index(values.shape[axis], 1), axis=axis)


def predecessor_values(values: ArrayLike, axis: int = -1) -> NDArray:
    """What each robot's CW predecessor holds of ``values`` (robots along ``axis``): ``np.roll(values,
    1, axis)`` (see :func:`successor_values`)."""
    values = np.asarray(values)
    return values.take(cyclic_index(values.shape[axis], -1), axis=axis)


@lru_cache(maxsize=64)
def cyclic_index(count: int, shift: int) -> NDArray[np.intp]:
    """Indices ``(i + shift) mod count`` of a ring of ``count`` robots (read-only: shared by callers)."""
    index = (np.arange(count) + shift) % count
    index.setflags(write=False)
    return index


Neighbours = Callable[[NDArray], NDArray]  # what each robot's neighbour on one side holds of values


def ring_gaps(angles: ArrayLike, successor: Neighbours = successor_values) -> FloatArray:
    """CCW gaps ``d_i^+ = wrap(theta_{i+1} - theta_i)`` (radians) of whole rings: robots along the
    last axis, or laid out as ``successor`` (what each robot's successor holds) says."""
    angles = np.asarray(angles, dtype=float)
    return wrap(successor(angles) - angles)


def midpoint_errors(angles: ArrayLike, successor: Neighbours = successor_values,
                    predecessor: Neighbours = predecessor_values) -> FloatArray:
    """``e_i = V_i - theta_i = (d_i^+ - d_i^-) / 4`` (radians) of whole rings with exact information
    (robots along the last axis, or laid out as ``successor`` and ``predecessor`` say)."""
    gaps = ring_gaps(angles, successor)
    return (gaps - predecessor(gaps)) / 4.0


def ring_neighbours(robot: int, alive: set[int] | frozenset[int]) -> tuple[int, int]:
    """``(predecessor, successor)`` of ``robot`` in the ring of the ``alive`` robots: the nearest
    alive ids before and after it in cyclic id order (itself when it is alone)."""
    return neighbours_in_ring(robot, sorted(alive))


def neighbours_in_ring(robot: int, ring: Sequence[int]) -> tuple[int, int]:
    """:func:`ring_neighbours` of ``robot`` in ``ring``, the alive ids in ascending order (``robot``
    among them or not): a bisection, for a world that asks for every robot of a large team each step."""
    start = bisect_left(ring, robot)
    end = start + 1 if start < len(ring) and ring[start] == robot else start  # first id above robot
    if len(ring) == end - start:
        return robot, robot
    return ring[start - 1], ring[end % len(ring)]
