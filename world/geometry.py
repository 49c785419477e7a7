"""Geometry of a convex polygonal region Q and its boundary (docs/algorithms.md sections 1, 10, 11).

Conventions used throughout:

* points are in metres, numpy arrays of shape ``(..., 2)``;
* angles are in radians, measured counter-clockwise (CCW) from the +x axis;
* the arc-length parameter ``s`` (metres) runs CCW along the boundary from vertex 0, in ``[0, L)``;
* the map ``phi_o`` sends a boundary point ``p`` to the angle ``atan2(p - o)`` seen from an interior
  centre ``o`` (the target or its estimate); ``boundary_point`` is its inverse.

Q is stored as ``{x : n_k . x <= c_k for every edge k}`` with unit outward normals ``n_k`` and offsets
``c_k``; ``h_k(o) = c_k - n_k . o`` is the distance from ``o`` to the line of edge k.
"""

from __future__ import annotations

from functools import cached_property
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.elementwise import reduce_last

TWO_PI = 2.0 * np.pi

FloatArray = NDArray[np.float64]


class RegionError(ValueError):
    """A region or a point in it is unusable; the message is one line naming the problem and the fix."""


def dot_rows(vectors: ArrayLike, rows: FloatArray) -> FloatArray:
    """``vectors . rows_k``: 2-D vectors (shape ``(..., 2)``) against each row of ``rows`` (shape
    ``(K, 2)``), shape ``(..., K)``. Written out as ``x x_k + y y_k`` rather than ``@`` or ``einsum``,
    whose rounding depends on the shapes they are given (a matrix product picks its kernel by
    shape): one robot's process and the engine's batched team then compute the same bits."""
    vectors = np.asarray(vectors, dtype=float)
    return vectors[..., None, 0] * rows[:, 0] + vectors[..., None, 1] * rows[:, 1]


def angle_of(point: ArrayLike, centre: ArrayLike) -> FloatArray:
    """``phi_centre(point)``: the angle (radians, CCW, in (-pi, pi]) of ``point`` seen from ``centre``.
    One point about one centre (both arrays of shape ``(2,)``, a robot's own view) is differenced in
    floats: the same bits, without numpy's cost per call."""
    if isinstance(point, np.ndarray) and isinstance(centre, np.ndarray) and point.shape == centre.shape == (2,):
        (x, y), (centre_x, centre_y) = point.tolist(), centre.tolist()
        return np.arctan2(y - centre_y, x - centre_x)
    delta = np.asarray(point, dtype=float) - np.asarray(centre, dtype=float)
    return np.arctan2(delta[..., 1], delta[..., 0])


def _first_crossing(points: FloatArray) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges (edge k joins vertex k to k + 1) that intersect."""
    count = len(points)
    following = np.roll(points, -1, axis=0)

    def side(a: FloatArray, b: FloatArray, c: FloatArray) -> float:
        return float(np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])))

    for first in range(count):
        for second in range(first + 2, count):
            if first == 0 and second == count - 1:
                continue  # adjacent through vertex 0
            p, q, r, t = points[first], following[first], points[second], following[second]
            if side(p, q, r) * side(p, q, t) < 0 and side(r, t, p) * side(r, t, q) < 0:
                return first, second
    return None


class ConvexRegion:
    """A strictly convex polygon with its vertices stored counter-clockwise.

    Build it with :meth:`from_vertices`, which validates the vertex list; the constructor assumes a
    valid CCW list.
    """

    def __init__(self, vertices: FloatArray) -> None:
        self.vertices: FloatArray = vertices
        following = np.roll(vertices, -1, axis=0)
        edges = following - vertices
        self.edge_lengths: FloatArray = np.hypot(edges[:, 0], edges[:, 1])
        self.directions: FloatArray = edges / self.edge_lengths[:, None]
        # Right-hand normal of a CCW edge points outwards.
        self.normals: FloatArray = np.stack([self.directions[:, 1], -self.directions[:, 0]], axis=1)
        self.offsets: FloatArray = np.einsum("kd,kd->k", self.normals, vertices)
        self.vertex_arc: FloatArray = np.concatenate([[0.0], np.cumsum(self.edge_lengths)])
        self.perimeter: float = float(self.vertex_arc[-1])

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_vertices(cls, vertices: ArrayLike) -> ConvexRegion:
        """Validate ``vertices`` (a list of (x, y) in metres, either orientation) and build the region.

        Refuses fewer than three vertices, non-finite values, repeated vertices, crossing edges
        (self-intersecting lists), zero area, collinear consecutive vertices and reflex (non-convex)
        corners, each with a :class:`RegionError` naming the offending vertex or edges. A clockwise
        list is reordered to CCW while keeping vertex 0 first.
        """
        try:
            points = np.asarray(vertices, dtype=float)
        except (TypeError, ValueError):
            raise RegionError("region.vertices must be a list of [x, y] number pairs") from None
        if points.size == 0:
            points = points.reshape(0, 2)
        if points.ndim != 2 or points.shape[1] != 2:
            raise RegionError("region.vertices must be a list of [x, y] number pairs")
        count = len(points)
        if count < 3:
            raise RegionError(f"region.vertices has {count} vertices; a polygon needs at least 3")
        if not np.all(np.isfinite(points)):
            raise RegionError("region.vertices contains NaN or infinity; give finite coordinates")
        scale = float(np.ptp(points, axis=0).max())
        separation = np.hypot(*(points[:, None, :] - points[None, :, :]).transpose(2, 0, 1))
        for first, second in zip(*np.nonzero(np.triu(separation <= 1e-12 * max(scale, 1.0), k=1)), strict=True):
            raise RegionError(f"region.vertices {first} and {second} coincide; remove the repeated vertex")
        edges = np.roll(points, -1, axis=0) - points
        crossing = _first_crossing(points)
        if crossing is not None:
            raise RegionError(
                f"region edges {crossing[0]} and {crossing[1]} cross (self-intersecting); list the corners in order"
            )
        area2 = float(np.sum(points[:, 0] * np.roll(points[:, 1], -1) - np.roll(points[:, 0], -1) * points[:, 1]))
        if abs(area2) <= 1e-12 * scale * scale:
            raise RegionError("region.vertices enclose zero area; give a polygon with an interior")
        orientation = np.sign(area2)  # +1 counter-clockwise, -1 clockwise
        incoming = np.roll(edges, 1, axis=0)
        turn_cross = orientation * (incoming[:, 0] * edges[:, 1] - incoming[:, 1] * edges[:, 0])
        tolerance = 1e-12 * scale * scale
        for k in range(count):
            if turn_cross[k] < -tolerance:
                raise RegionError(
                    f"region is not convex at vertex {k} {points[k].tolist()}; give a convex polygon"
                )
            if abs(turn_cross[k]) <= tolerance:
                raise RegionError(
                    f"region.vertices {(k - 1) % count}, {k}, {(k + 1) % count} are collinear; remove vertex {k}"
                )
        if orientation < 0:  # clockwise: reverse, keeping vertex 0 first
            points = np.concatenate([points[:1], points[:0:-1]])
        return cls(points)

    # ------------------------------------------------------------------ interior
    def heights(self, centre: ArrayLike) -> FloatArray:
        """``h_k(centre)``: signed distances (metres, shape ``(..., M)``) from ``centre`` to each edge line;
        all positive exactly when ``centre`` is interior."""
        return self.offsets - dot_rows(centre, self.normals)

    def on_boundary(self, point: ArrayLike, tolerance: float) -> NDArray[np.bool_] | np.bool_:
        """Whether ``point`` lies on the boundary within ``tolerance`` metres: inside every edge line
        up to it and on at least one. One point given as an ``(x, y)`` tuple of floats (as a message
        carries it) is checked in plain floats, the same operations as :meth:`heights` in the same
        order, without numpy's cost per call (a world checks every robot's goal each step)."""
        if isinstance(point, tuple) and len(point) == 2 and all(type(value) is float for value in point):
            x, y = point
            lines = self._edge_lines
            edge_heights = [offset - (x * normal_x + y * normal_y) for offset, normal_x, normal_y in lines]
            return np.bool_(min(edge_heights) >= -tolerance and min(map(abs, edge_heights)) <= tolerance)
        heights = self.heights(point)
        nearest = reduce_last(np.minimum, heights), reduce_last(np.minimum, np.abs(heights))
        return (nearest[0] >= -tolerance) & (nearest[1] <= tolerance)

    @cached_property
    def _edge_lines(self) -> list[tuple[float, float, float]]:
        """``(offset, normal x, normal y)`` of each edge line as plain floats."""
        pairs = zip(self.offsets, self.normals, strict=True)
        return [(float(offset), float(normal[0]), float(normal[1])) for offset, normal in pairs]

    def is_interior(self, point: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
        """Whether ``point`` lies in the interior, at least ``margin`` metres from every edge line."""
        return reduce_last(np.logical_and, self.heights(point) > margin)

    def require_interior(self, point: ArrayLike, field: str) -> None:
        """Raise :class:`RegionError` naming ``field`` unless ``point`` is strictly inside the region."""
        if not bool(np.all(self.is_interior(point))):
            raise RegionError(
                f"{field} {np.asarray(point).tolist()} is not inside the region; move it inside the polygon"
            )

    def clamp_interior(self, point: ArrayLike, margin: float) -> FloatArray:
        """Pull ``point`` towards the Chebyshev centre until it is ``margin`` metres inside every edge.

        Used for an estimate that left Q, where ``phi`` stops being a bijection (docs/algorithms.md section 1).
        Points already that deep inside are returned unchanged.
        """
        point = np.asarray(point, dtype=float)
        centre, radius = self.chebyshev_centre
        if margin >= radius:
            raise RegionError(f"clamp margin {margin} m exceeds the inscribed radius {radius:.6g} m")
        outward = point - centre
        reach = dot_rows(outward, self.normals)
        room = self.offsets - margin - dot_rows(centre, self.normals)
        with np.errstate(divide="ignore", invalid="ignore"):
            limits = np.where(reach > 0, room / reach, np.inf)
        fraction = np.minimum(reduce_last(np.minimum, limits), 1.0)
        return centre + fraction[..., None] * outward

    # ------------------------------------------------------------------ boundary map
    def boundary_point(self, theta: ArrayLike, centre: ArrayLike) -> FloatArray:
        """``phi_centre^{-1}(theta)``: the boundary point seen from interior ``centre`` at angle ``theta``.

        ``theta`` (radians) of shape ``S`` and ``centre`` of shape ``(..., 2)`` broadcast; the result has
        shape ``S + (2,)``. With ``u = (cos theta, sin theta)``, ``t* = min over n_k.u > 0 of
        h_k(centre) / (n_k.u)`` and the point is ``centre + t* u``.

        One angle (a float) about one centre (shape ``(2,)``), a robot's goal each step, is done in
        plain floats: the same operations in the same order, so the same bits, without numpy's cost
        per call.
        """
        if isinstance(theta, float) and isinstance(centre, np.ndarray) and centre.shape == (2,):
            return self._boundary_point_of_one(theta, centre)
        theta = np.asarray(theta, dtype=float)
        direction = np.empty(theta.shape + (2,))  # (cos, sin) on the last axis, as np.stack would put them
        direction[..., 0] = np.cos(theta)  # computed whole, then copied: the same bits as before
        direction[..., 1] = np.sin(theta)
        approach = dot_rows(direction, self.normals)
        heights = self.heights(centre)
        with np.errstate(divide="ignore", over="ignore"):
            reach = np.where(approach > 0, heights / approach, np.inf)
        return np.asarray(centre, dtype=float) + reduce_last(np.minimum, reach)[..., None] * direction

    def _boundary_point_of_one(self, theta: float, centre: FloatArray) -> FloatArray:
        """:meth:`boundary_point` of one angle (radians) about one centre (metres, ``(2,)``)."""
        cos, sin = float(np.cos(theta)), float(np.sin(theta))
        centre_x, centre_y = centre.tolist()
        reach = np.inf
        for offset, normal_x, normal_y in self._edge_lines:
            approach = cos * normal_x + sin * normal_y
            if approach > 0:
                reach = min(reach, (offset - (centre_x * normal_x + centre_y * normal_y)) / approach)
        return np.array((centre_x + reach * cos, centre_y + reach * sin))

    def arc_length(self, point: ArrayLike) -> FloatArray:
        """Arc length ``s`` (metres, CCW from vertex 0, in ``[0, L)``) of a boundary point."""
        point = np.asarray(point, dtype=float)
        relative = point[..., None, :] - self.vertices
        along_edge = relative[..., 0] * self.directions[:, 0] + relative[..., 1] * self.directions[:, 1]
        along = np.clip(along_edge, 0.0, self.edge_lengths)
        foot = self.vertices + along[..., None] * self.directions
        gap = np.sum((point[..., None, :] - foot) ** 2, axis=-1)
        edge = np.argmin(gap, axis=-1)
        s = self.vertex_arc[edge] + np.take_along_axis(along, edge[..., None], axis=-1)[..., 0]
        return np.mod(s, self.perimeter)

    def point_at(self, s: ArrayLike) -> FloatArray:
        """The boundary point at arc length ``s`` (metres, taken modulo the perimeter)."""
        along = np.mod(np.asarray(s, dtype=float), self.perimeter)
        edge = np.clip(np.searchsorted(self.vertex_arc, along, side="right") - 1, 0, len(self.vertices) - 1)
        point: FloatArray = self.vertices[edge] + (along - self.vertex_arc[edge])[..., None] * self.directions[edge]
        return point

    def move_along(self, start: ArrayLike, goal: ArrayLike, max_distance: float | None) -> FloatArray:
        """Move from boundary point ``start`` towards ``goal`` along the shorter boundary arc, at most
        ``max_distance`` metres (``None``: no cap). Returns a new array (``goal``'s values wherever it
        is reachable): a caller that changes ``goal`` afterwards does not move what it got."""
        goal = np.asarray(goal, dtype=float)
        if max_distance is None:
            return goal.copy()
        s_start = self.arc_length(start)
        half = 0.5 * self.perimeter
        shift = np.mod(self.arc_length(goal) - s_start + half, self.perimeter) - half
        reachable = np.abs(shift) <= max_distance
        capped = self.point_at(s_start + np.clip(shift, -max_distance, max_distance))
        return np.where(reachable[..., None], goal, capped)

    # ------------------------------------------------------------------ sizes (section 11)
    @cached_property
    def chebyshev_centre(self) -> tuple[FloatArray, float]:
        """Centre (metres) and radius of the largest inscribed disc: ``max r s.t. n_k.c + r <= c_k``.

        A linear programme in ``(c, r)`` whose optimum lies where three edge constraints are tight:
        every triple of edges is solved exactly (3 x 3, batched), and of the feasible solutions the
        largest radius wins, the mean of the ties where the optimum is not unique (a rectangle's
        centre line: its midpoint). Exact, and no optimiser to import in a robot process."""
        edges = np.array(list(combinations(range(len(self.normals)), 3)))
        systems = np.concatenate([self.normals[edges], np.ones((len(edges), 3, 1))], axis=2)
        solvable = np.abs(np.linalg.det(systems)) > 1e-12
        solutions = np.linalg.solve(systems[solvable], self.offsets[edges[solvable]][..., None])[..., 0]
        centres, radii = solutions[:, :2], solutions[:, 2]
        slack = 1e-9 * max(self.outer_diameter, 1.0)
        feasible = np.all(dot_rows(centres, self.normals) + radii[:, None] <= self.offsets + slack, axis=1)
        best = radii[feasible].max()
        tied = feasible & (radii >= best - slack)
        return centres[tied].mean(axis=0), float(radii[tied].mean())

    @property
    def inner_diameter(self) -> float:
        """``D_in``: diameter (metres) of the largest inscribed disc."""
        return 2.0 * self.chebyshev_centre[1]

    @cached_property
    def outer_diameter(self) -> float:
        """``D_out``: the longest segment in the polygon (metres), which joins two vertices."""
        gaps = self.vertices[:, None, :] - self.vertices[None, :, :]
        return float(np.sqrt(np.max(np.sum(gaps**2, axis=-1))))

    # ------------------------------------------------------------------ speed (section 10)
    def omega_max(self, v_max: float, dt: float, centre: ArrayLike, samples: int = 20_000) -> float:
        """Largest angular speed (rad/s) about ``centre`` that no boundary move of at most
        ``d_max = v_max * dt`` metres can exceed in one step of ``dt`` seconds:

        ``omega_max = (1/dt) * min over s of wrap(theta(s + d_max) - theta(s))``

        for point robots (no turn-in-place time at vertices). ``s`` is sampled densely and at every
        vertex and vertex - ``d_max``, where the minimum of a sliding window is attained.
        """
        d_max = v_max * dt
        if d_max >= self.perimeter:
            raise RegionError(f"control.v_max * control.dt = {d_max:.6g} m is at least the perimeter "
                              f"{self.perimeter:.6g} m; lower v_max or dt")
        centre = np.asarray(centre, dtype=float)
        starts = np.concatenate(
            [
                np.linspace(0.0, self.perimeter, samples, endpoint=False),
                self.vertex_arc[:-1],
                self.vertex_arc[:-1] - d_max,
            ]
        )
        swept = np.mod(
            angle_of(self.point_at(starts + d_max), centre) - angle_of(self.point_at(starts), centre), TWO_PI
        )
        return float(swept.min() / dt)
