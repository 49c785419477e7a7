"""The modified strategy for a limited communication range ``r_c`` (docs/algorithms.md section 11).

A ring neighbour is reachable when it is within ``r_c`` metres at the start of the step. Then:

* neither neighbour reachable: the robot stays;
* exactly one reachable: it moves at ``omega_max`` towards the unreachable neighbour's side (away
  from the reachable one);
* both reachable: the self-triggered (or constant) midpoint law as usual;

and in the last two cases the step is shortened (bisection on its angle) so that every reachable
link stays within ``r_c``: the distance to the neighbour's remembered position must stay within
``r_c`` less how far the neighbour may have moved since (its *slack*), and a link already past that
may only shorten. Both ends keeping to this, the true link never exceeds ``r_c``. Angles in radians,
distances in metres; every function broadcasts over robots and trials.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.elementwise import reduce_last
from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.ring import successor_values

BISECTIONS = 30


def range_limited_step(step: ArrayLike, reach_minus: ArrayLike, reach_plus: ArrayLike, max_step: float) -> FloatArray:
    """The angular step (radians) before clipping: the law's ``step`` with both neighbours
    reachable, ``+max_step`` (CCW, towards the successor) when only the predecessor is reachable,
    ``-max_step`` when only the successor is, 0 when neither."""
    reach_minus = np.asarray(reach_minus, dtype=bool)
    reach_plus = np.asarray(reach_plus, dtype=bool)
    one_sided = np.where(reach_minus, max_step, -max_step)
    return np.where(reach_minus & reach_plus, step, np.where(reach_minus ^ reach_plus, one_sided, 0.0))


def boundary_stretch(region: ConvexRegion, centre: ArrayLike) -> FloatArray:
    """The most boundary distance (metres) per radian seen from ``centre``: on edge k,
    ``|dp/dtheta| = r^2 / h_k <= R_k^2 / h_k`` with ``R_k`` the farther end of the edge
    (docs/algorithms.md section 1)."""
    centre = np.asarray(centre, dtype=float)
    heights = region.heights(centre)
    reach = np.linalg.norm(region.vertices - centre[..., None, :], axis=-1)
    farther = np.maximum(reach, successor_values(reach))
    return reduce_last(np.maximum, farther**2 / heights)


def clip_to_range(
    region: ConvexRegion,
    centre: ArrayLike,
    theta: ArrayLike,
    step: ArrayLike,
    anchors: Sequence[tuple[ArrayLike, ArrayLike, ArrayLike]],
    communication_range: float,
) -> FloatArray:
    """Shorten ``step`` so that, for every ``(anchor position, applies, slack)`` where ``applies``,
    the new position stays within ``communication_range - slack`` of the anchor, or no farther than
    it is now if it is already beyond that."""
    theta = np.asarray(theta, dtype=float)
    step = np.asarray(step, dtype=float)

    def distances(fraction: FloatArray) -> list[FloatArray]:
        point = region.boundary_point(theta + fraction * step, centre)
        return [np.linalg.norm(point - np.asarray(anchor), axis=-1) for anchor, _, _ in anchors]

    start = distances(np.zeros_like(step))
    bounds = [np.maximum(communication_range - np.asarray(slack), now)
              for now, (_, _, slack) in zip(start, anchors, strict=True)]

    def admissible(fraction: FloatArray) -> FloatArray:
        ok = np.ones(np.broadcast(theta, step).shape, dtype=bool)
        for distance, bound, (_, applies, _) in zip(distances(fraction), bounds, anchors, strict=True):
            ok &= ~np.asarray(applies, dtype=bool) | (distance <= bound)
        return ok

    full = admissible(np.ones_like(step))
    if np.all(full):
        return step
    low, high = np.zeros_like(step), np.ones_like(step)
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        good = admissible(middle)
        low, high = np.where(good, middle, low), np.where(good, high, middle)
    return np.where(full, step, low * step)
