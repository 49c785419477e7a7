"""Communication and sensing ranges (docs/algorithms.md section 11). Distances in metres.

* Necessary (paper Thm 1): ``r_c >= D_in sin(pi / N)`` and ``r_s >= D_in / 2``.
* Sufficient for sensing: ``r_s >= D_out``.
* The paper's ``r_c >= L / N`` is *not* sufficient (unit square, N = 6, target (0.2, 0.2) needs 0.828);
  safe choices are ``r_c >= D_out`` or the longest link of the best angle-uniform configuration for
  the given target, :func:`uniform_link_requirement`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.ring import successor_values


def uniform_ring(region: ConvexRegion, centre: ArrayLike, robots: int, rotation: ArrayLike = 0.0) -> FloatArray:
    """Boundary points of ``robots`` robots spaced ``2 pi / robots`` apart about ``centre``, the first at
    angle ``rotation`` (radians; an array of rotations gives shape ``rotation.shape + (robots, 2)``)."""
    rotation = np.asarray(rotation, dtype=float)
    angles = rotation[..., None] + 2.0 * np.pi * np.arange(robots) / robots
    return region.boundary_point(angles, centre)


def link_distance(start: ArrayLike, end: ArrayLike) -> FloatArray:
    """Distances (metres) between points (last axis x, y): the one computation of a link's length
    that the world, the engine and the radio all use, so they agree to the last bit."""
    difference = np.asarray(end, dtype=float) - np.asarray(start, dtype=float)
    return np.sqrt(difference[..., 0] * difference[..., 0] + difference[..., 1] * difference[..., 1])


def link_lengths(positions: ArrayLike) -> FloatArray:
    """Distances (metres) from each robot to its CCW successor along axis -2 of ``positions``."""
    positions = np.asarray(positions, dtype=float)
    return link_distance(positions, successor_values(positions, axis=-2))


def uniform_link_requirement(
    region: ConvexRegion, centre: ArrayLike, robots: int, samples: int = 4096
) -> tuple[float, float]:
    """The smallest ``r_c`` that keeps every ring link of *some* angle-uniform configuration about
    ``centre`` connected: ``min over rotations t0 of max_i ||p_{i+1} - p_i||``.

    Rotations are sampled on ``[0, 2 pi / robots)`` (the configuration repeats with that period).
    Returns ``(r_c, best rotation in radians)``.
    """
    rotations = np.linspace(0.0, 2.0 * np.pi / robots, samples, endpoint=False)
    longest = link_lengths(uniform_ring(region, centre, robots, rotations)).max(axis=-1)
    best = int(np.argmin(longest))
    return float(longest[best]), float(rotations[best])


@dataclass(frozen=True)
class RangeBounds:
    """Range bounds (metres) for a region, a team size and a target."""

    perimeter: float  # L
    inner_diameter: float  # D_in
    outer_diameter: float  # D_out
    necessary_communication: float  # D_in sin(pi / N)
    necessary_sensing: float  # D_in / 2
    paper_communication: float  # L / N, the paper's (insufficient) Theorem 2 bound
    safe_communication: float  # min over rotations of the longest uniform link, for this target
    safe_sensing: float  # D_out


PATH_SAMPLES = 48  # target positions checked along a moving target's path


def safe_communication_range(region: ConvexRegion, path: ArrayLike, robots: int) -> float:
    """The communication range (metres) a team of ``robots`` needs to stay linked in its
    angle-uniform configuration about every target position of ``path`` (shape ``(K, 2)``,
    metres): the longest link of :func:`uniform_link_requirement`, worst over at most
    ``PATH_SAMPLES`` evenly spread positions."""
    positions = np.asarray(path, dtype=float)
    samples = positions[np.linspace(0, len(positions) - 1, min(PATH_SAMPLES, len(positions))).astype(int)]
    return max(uniform_link_requirement(region, point, robots)[0] for point in samples)


def range_bounds(region: ConvexRegion, centre: ArrayLike, robots: int) -> RangeBounds:
    """All bounds of docs/algorithms.md section 11 for ``robots`` robots around ``centre``."""
    d_in = region.inner_diameter
    return RangeBounds(
        perimeter=region.perimeter,
        inner_diameter=d_in,
        outer_diameter=region.outer_diameter,
        necessary_communication=d_in * float(np.sin(np.pi / robots)),
        necessary_sensing=d_in / 2.0,
        paper_communication=region.perimeter / robots,
        safe_communication=uniform_link_requirement(region, centre, robots)[0],
        safe_sensing=region.outer_diameter,
    )
