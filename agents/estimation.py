"""Range-only estimation of the target position (docs/algorithms.md section 7).

State ``x = o`` (metres, 2-D), random-walk model ``x(k) = x(k-1) + w``, ``w ~ N(0, q I)`` per step,
and ranges ``z_j = ||o - p_j|| + v_j``, ``v_j ~ N(0, sigma_z^2)`` from robots at ``p_j``. Naming
follows filterpy (and not the paper, which swaps them): ``Q`` is the process noise, ``R`` the
measurement noise. The filter is filterpy's :class:`~filterpy.kalman.ExtendedKalmanFilter`, with
the shape care filterpy needs: ``z`` as a column, ``h(x)`` as a column, an explicit ``(m, m)`` R for
``m`` ranges, and ``predict()`` then ``update()``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.agents.fusion import covariance_intersection, sequential_intersection
from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.params import EstimationParams

SINGULAR_DISTANCE = 1e-9  # m: a robot this close to the estimate gives no usable bearing (0/0 Jacobian)
# Robots whose spread across their line is below this fraction of their spread along it are on one
# line (up to rounding: points of one boundary edge are not exactly collinear in floating point).
COLLINEAR = 1e-9


class NoFix(ValueError):
    """The ranges do not fix the target: fewer than three, or from robots all on one line."""


def _ranges(x: FloatArray, positions: FloatArray) -> FloatArray:
    """``h(x)``: distances (column, m) from the robots at ``positions`` to the state ``x`` (2, 1)."""
    return np.linalg.norm(x[:, 0] - positions, axis=1).reshape(-1, 1)


def _jacobian(x: FloatArray, positions: FloatArray) -> FloatArray:
    """``H``: rows ``(x - p_j)^T / ||x - p_j||`` (m, 2)."""
    offsets = x[:, 0] - positions
    return offsets / np.linalg.norm(offsets, axis=1, keepdims=True)


class RangeFilter:
    """One range-only EKF: a robot's own (one range per step) or a fusion centre's (all ranges).

    ``mean`` (metres) and ``covariance`` (m^2) are the prior; ``process_noise`` is ``q`` in
    ``Q = q I`` (m^2 per step); ``range_sigma`` is ``sigma_z`` (metres).
    """

    def __init__(self, mean: ArrayLike, covariance: ArrayLike, process_noise: float, range_sigma: float) -> None:
        # filterpy imports scipy.stats and matplotlib (0.8 s, ~90 MiB): only processes that estimate pay.
        from filterpy.kalman import ExtendedKalmanFilter

        self.ekf = ExtendedKalmanFilter(dim_x=2, dim_z=1)
        self.ekf.F = np.eye(2)
        self.ekf.Q = process_noise * np.eye(2)
        self.range_sigma = range_sigma
        self.adopt(mean, covariance)

    @property
    def mean(self) -> FloatArray:
        return self.ekf.x[:, 0].copy()

    @property
    def covariance(self) -> FloatArray:
        """``P`` made exactly symmetric (the Joseph update leaves rounding asymmetry), so a belief
        sent as ``(xx, xy, yy)`` is the very matrix the sender holds."""
        return 0.5 * (self.ekf.P + self.ekf.P.T)

    def adopt(self, mean: ArrayLike, covariance: ArrayLike) -> None:
        """Replace the estimate (a prior, or the result of fusing with the neighbours' beliefs)."""
        self.ekf.x = np.array(mean, dtype=float).reshape(2, 1)
        self.ekf.P = np.array(covariance, dtype=float).reshape(2, 2)

    def step(self, positions: ArrayLike, ranges: ArrayLike) -> None:
        """Predict one step, then update with the ranges measured from ``positions`` (m, 2)."""
        self.ekf.predict()
        self.update(positions, ranges)

    def update(self, positions: ArrayLike, ranges: ArrayLike) -> None:
        """Update with the ranges measured from ``positions`` (m, 2). Missing ranges (NaN: beyond
        the sensing range) and robots within ``SINGULAR_DISTANCE`` of the predicted estimate are
        skipped; with none left the step is prediction only.
        """
        points = np.asarray(positions, dtype=float).reshape(-1, 2)
        measured = np.asarray(ranges, dtype=float).reshape(-1)
        distances = np.linalg.norm(self.ekf.x[:, 0] - points, axis=1)
        usable = np.isfinite(measured) & (distances > SINGULAR_DISTANCE)
        if not usable.any():
            return
        points, measured = points[usable], measured[usable]
        noise = self.range_sigma**2 * np.eye(len(measured))
        self.ekf.update(measured.reshape(-1, 1), _jacobian, _ranges, R=noise, args=(points,), hx_args=(points,))


def trilaterate(positions: ArrayLike, ranges: ArrayLike, range_sigma: float, refinements: int = 5,
                inflation: float = 10.0) -> tuple[FloatArray, FloatArray]:
    """Target position from ranges of three or more non-collinear robots, and a covariance for it.

    Linear least squares on ``2 (p_j - p_0)^T o = z_0^2 - z_j^2 + ||p_j||^2 - ||p_0||^2``, refined by
    ``refinements`` Gauss-Newton steps; covariance ``inflation * sigma_z^2 (H^T H)^{-1}`` (m^2).
    Missing ranges (NaN) are skipped; :class:`NoFix` when the rest do not fix the target.
    """
    every_point = np.asarray(positions, dtype=float)
    every_range = np.asarray(ranges, dtype=float)
    usable = np.isfinite(every_range)
    points, measured = every_point[usable], every_range[usable]
    if len(measured) < 3:
        raise NoFix(f"trilateration needs ranges from at least 3 robots, got {len(measured)}")
    first, rest = points[0], points[1:]
    system = 2.0 * (rest - first)
    if np.linalg.matrix_rank(system, rtol=COLLINEAR) < 2:
        raise NoFix("trilateration needs robots that are not all on one line")
    rhs = measured[0] ** 2 - measured[1:] ** 2 + np.sum(rest**2, axis=1) - np.sum(first**2)
    estimate, *_ = np.linalg.lstsq(system, rhs, rcond=None)
    for _ in range(refinements):
        x = estimate.reshape(2, 1)
        jacobian = _jacobian(x, points)
        residual = measured - _ranges(x, points)[:, 0]
        estimate = estimate + np.linalg.lstsq(jacobian, residual, rcond=None)[0]
    jacobian = _jacobian(estimate.reshape(2, 1), points)
    covariance = inflation * range_sigma**2 * np.linalg.inv(jacobian.T @ jacobian)
    return np.asarray(estimate, dtype=float), np.asarray(covariance, dtype=float)


# ---------------------------------------------------------------------------- configured estimators


def prior_belief(
    params: EstimationParams, region: ConvexRegion, truth_at_start: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """The belief ``(mean, covariance)`` (metres, m^2) an estimator starts from: the configured
    prior, or for "trilateration" the uninformative one (see :class:`Estimator`)."""
    if params.prior == "trilateration":
        return region.chebyshev_centre[0].copy(), region.outer_diameter**2 * np.eye(2)
    mean = truth_at_start if params.prior == "truth" else params.prior
    return np.array(mean, dtype=float), params.prior_variance * np.eye(2)


class Estimator:
    """The belief about the target of one decentralized robot or of the fusion centre.

    Every step: :meth:`measure` (predict, then update with the ranges it has); a decentralized robot
    that polled then :meth:`fuse` its neighbours' beliefs. After each of these the filter's own mean
    is kept inside the region shrunk by ``params.margin`` metres (:meth:`keep_inside`), so what it
    predicts from, replies with and fuses is a centre the boundary map works about: seen from a
    centre on (or microns from) an edge, boundary speeds ``r^2 / h`` explode, ring order breaks and
    the self-triggered rule stops firing. :attr:`centre`, the point a robot steers about, is that
    mean.

    With the "trilateration" prior, the ranges of the first step are trilaterated into the prior
    when they fix the target (three or more, from robots not all on one line). When they do not
    (a limited sensing range leaves fewer, or the robots in range share an edge), the prior is
    uninformative instead, the region's Chebyshev centre with variance ``D_out^2`` (m^2) in every
    direction, which covers the whole region, and the first step updates it with the ranges there
    are like any other step.
    """

    def __init__(self, params: EstimationParams, region: ConvexRegion, truth_at_start: ArrayLike) -> None:
        self.params = params
        self.region = region
        self.filter = RangeFilter(*prior_belief(params, region, truth_at_start), params.process_noise,
                                  params.range_sigma)
        self.keep_inside()
        self.started = False

    @property
    def belief(self) -> tuple[FloatArray, FloatArray]:
        """``(mean, covariance)`` of the filter (metres, m^2)."""
        return self.filter.mean, self.filter.covariance

    @property
    def centre(self) -> FloatArray:
        """The estimate (metres) a robot steers about: the filter's mean, inside by ``params.margin``."""
        return self.filter.mean

    def keep_inside(self) -> None:
        """Pull the filter's mean ``params.margin`` metres inside the region if it is not that deep
        (covariance unchanged); a mean already inside is left exactly as it is."""
        mean = self.filter.mean
        if not bool(self.region.is_interior(mean, self.params.margin)):
            self.filter.ekf.x = self.region.clamp_interior(mean, self.params.margin).reshape(2, 1)

    def measure(self, positions: ArrayLike, ranges: ArrayLike,
                told: Sequence[tuple[ArrayLike, ArrayLike]] = ()) -> None:
        """Fold in one step's ranges from robots at ``positions`` (NaN: no range). With the
        "trilateration" prior, the first step's ranges become the prior instead when they fix the
        target (see the class). Beliefs ``told`` by neighbours (``(mean, covariance)``) are fused
        by :meth:`fuse` between the prediction and the update, so the step's own ranges update
        the fused prior with their full Kalman weight."""
        first, self.started = not self.started, True
        if first and self.params.prior == "trilateration":
            try:
                self.filter.adopt(*trilaterate(positions, ranges, self.params.range_sigma))
            except NoFix:
                pass  # the uninformative prior stands, updated below with the ranges there are
            else:
                self.keep_inside()
                return
        if told:
            self.filter.ekf.predict()
            self.fuse(told)
            self.filter.update(positions, ranges)
        else:
            self.filter.step(positions, ranges)
        self.keep_inside()

    def fuse(self, beliefs: Sequence[tuple[ArrayLike, ArrayLike]]) -> None:
        """Covariance-intersect the own belief with neighbours' ``(mean, covariance)`` and adopt it."""
        means = np.array([self.filter.mean, *(np.asarray(mean, dtype=float) for mean, _ in beliefs)])
        covariances = np.array([self.filter.covariance,
                                *(np.asarray(covariance, dtype=float) for _, covariance in beliefs)])
        combine = covariance_intersection if self.params.fusion == "ci" else sequential_intersection
        fused = combine(means, covariances, self.params.criterion)
        self.filter.adopt(fused.mean, fused.covariance)
        self.keep_inside()
