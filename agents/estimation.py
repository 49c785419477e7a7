"""Range-only estimation of the target position (docs/algorithms.md section 7), for a batch of filters.

State ``x = o`` (metres, 2-D), random-walk model ``x(k) = x(k-1) + w``, ``w ~ N(0, q I)`` per step,
and ranges ``z_j = ||o - p_j|| + v_j``, ``v_j ~ N(0, sigma_z^2)`` from robots at ``p_j``. Naming
follows filterpy (and not the paper, which swaps them): ``Q`` is the process noise, ``R`` the
measurement noise.

The extended Kalman filter is written here in numpy for a batch of ``B`` filters at once (every robot
of every trial of a study, or one robot process's own filter, a batch of one), every quantity a 2x2
matrix or a 2-vector computed component by component, elementwise along the batch: a filter's result
does not depend on the rest of its batch, so a robot process holds bit for bit the belief the engine
computes for it. The update with the ``m`` usable ranges of a step is the stacked EKF update with the
Joseph-form covariance, as filterpy's ``ExtendedKalmanFilter`` (the tests' independent oracle) does:

    K = P H^T (H P H^T + R)^-1,   x+ = x + K (z - h(x)),   P+ = (I - K H) P (I - K H)^T + K R K^T,

with ``H``'s rows ``(x - p_j)^T / ||x - p_j||`` at the predicted ``x`` and ``R = sigma_z^2 I``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.fusion import identity, intersect, intersect_in_order, sequential_sum
from ringtrack.agents.fusion_rows import few, intersect_rows
from ringtrack.world.elementwise import anywhere, everywhere
from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.params import EstimationParams
from ringtrack.world.target import steady_variance

SINGULAR_DISTANCE = 1e-9  # m: a robot this close to the estimate gives no usable bearing (0/0 Jacobian)
# Robots whose spread across their line is below this fraction of their spread along it are on one
# line (up to rounding: points of one boundary edge are not exactly collinear in floating point).
COLLINEAR = 1e-9
MARGIN_ROUNDING = 1e-9  # relative: a mean this close to the margin is on it (clamped before)


class NoFix(ValueError):
    """The ranges do not fix the target: fewer than three, or from robots all on one line."""


Belief = tuple[ArrayLike, ArrayLike]  # (mean (2,) metres, covariance (2, 2) m^2)


class Told(NamedTuple):
    """Beliefs other robots told each filter of a batch: ``means`` (B, k, 2) metres, ``covariances``
    (B, k, 2, 2) m^2, and which of the ``k`` slots hold one (``present``, (B, k))."""

    means: FloatArray
    covariances: FloatArray
    present: NDArray[np.bool_]

    @classmethod
    def by_sides(cls, predecessor: Belief | None, successor: Belief | None) -> Told:
        """What one robot was told by its predecessor and successor (``(mean, covariance)`` each, or
        None), as a batch of one with the engine's two slots, so that it fuses bit for bit as there."""
        told = (predecessor, successor)
        means = np.zeros((1, 2, 2))
        covariances = np.broadcast_to(np.eye(2), (1, 2, 2, 2)).copy()
        for side, belief in enumerate(told):
            if belief is not None:
                means[0, side], covariances[0, side] = belief
        return cls(means, covariances, np.array([[belief is not None for belief in told]]))

    def predicted(self, process_noise: float) -> Told:
        """The same beliefs a step older in meaning: ``P + q I`` (m^2)."""
        return self._replace(covariances=self.covariances + process_noise * identity(2))


class RangeFilters:
    """A batch of range-only EKFs: robots' own (one range per step each) or fusion centres' (all ranges).

    ``mean`` (B, 2) metres and ``covariance`` (B, 2, 2) m^2 are the priors; ``process_noise`` is ``q``
    in ``Q = q I`` (m^2 per step); ``range_sigma`` is ``sigma_z`` (metres).
    """

    def __init__(self, mean: ArrayLike, covariance: ArrayLike, process_noise: float, range_sigma: float) -> None:
        self.process_noise = process_noise
        self.range_sigma = range_sigma
        self.mean = np.array(mean, dtype=float).reshape(-1, 2)
        self.covariance = np.array(covariance, dtype=float).reshape(-1, 2, 2)

    def adopt(self, mean: ArrayLike, covariance: ArrayLike, rows: NDArray[np.bool_] | None = None) -> None:
        """Replace the estimates (of the ``rows`` given, default all) by ``mean``, ``covariance``
        (a prior, or the result of fusing with neighbours' beliefs)."""
        if rows is None or everywhere(rows):
            self.mean = np.array(mean, dtype=float).reshape(self.mean.shape)
            self.covariance = np.array(covariance, dtype=float).reshape(self.covariance.shape)
        else:
            self.mean = np.where(rows[:, None], mean, self.mean)
            self.covariance = np.where(rows[:, None, None], covariance, self.covariance)

    def predict(self) -> None:
        """The random walk's prediction: ``x`` unchanged, ``P + q I``."""
        self.covariance = self.covariance + self.process_noise * identity(2)

    def step(self, positions: ArrayLike, ranges: ArrayLike) -> None:
        """Predict one step, then update with the ranges measured from ``positions`` (B, m, 2)."""
        self.predict()
        self.update(positions, ranges)

    def update(self, positions: ArrayLike, ranges: ArrayLike) -> None:
        """Update with the ranges (B, m) measured from ``positions`` (B, m, 2), metres. Missing ranges
        (NaN: beyond the sensing range) and robots within ``SINGULAR_DISTANCE`` of the predicted
        estimate are skipped; a filter with none left only predicts this step."""
        points = np.asarray(positions, dtype=float).reshape(len(self.mean), -1, 2)
        measured = np.asarray(ranges, dtype=float).reshape(len(self.mean), -1)
        offsets = self.mean[:, :, None] - points.transpose(0, 2, 1)  # x - p_j, (B, 2, m)
        distances = np.hypot(offsets[:, 0], offsets[:, 1])
        usable = np.isfinite(measured) & (distances > SINGULAR_DISTANCE)
        if not anywhere(usable):
            return
        safe = np.where(usable, distances, 1.0)
        rows = np.where(usable[:, None], offsets / safe[:, None], 0.0)  # H^T, (B, 2, m)
        residual = np.where(usable, measured - distances, 0.0)
        covariance = self.covariance
        gain_numerator = _products(covariance, rows)  # P H^T, (B, 2, m)
        innovation = sequential_sum(rows[:, :, :, None] * gain_numerator[:, :, None, :], axis=1)  # H P H^T
        innovation = innovation + self.range_sigma**2 * identity(measured.shape[1])
        inverse = 1.0 / innovation if measured.shape[1] == 1 else np.linalg.inv(innovation)
        gain = sequential_sum(gain_numerator[:, :, :, None] * inverse[:, None, :, :], axis=2)  # K, (B, 2, m)
        mean = self.mean + sequential_sum(gain * residual[:, None, :], axis=2)
        # Joseph form: (I - K H) P (I - K H)^T + K R K^T
        keep = identity(2) - sequential_sum(gain[:, :, None, :] * rows[:, None, :, :], axis=3)  # I - K H
        kept = _products(_products(keep, covariance), keep.transpose(0, 2, 1))  # (I - K H) P (I - K H)^T
        noise = sequential_sum(gain[:, :, None, :] * gain[:, None, :, :], axis=3)  # K K^T
        covariance = kept + self.range_sigma**2 * noise
        covariance[:, 1, 0] = covariance[:, 0, 1]  # exactly symmetric
        self.adopt(mean, covariance, usable.any(axis=1))


    def absorb(self, positions: FloatArray, ranges: FloatArray, variances: FloatArray) -> None:
        """Update with ranges (B, m) taken from ``positions`` (B, m, 2), metres, each with its own
        variance (B, m), m^2, in information form linearised at the current mean ``x``: with
        ``h = (x - p) / ||x - p||``,

            P+ = (P^-1 + sum h h^T / v)^-1,   x+ = x + P+ sum h (z - ||x - p||) / v,

        the stacked EKF update with a diagonal ``R`` (used for the late ranges of
        :mod:`agents.relay`). NaN ranges and robots within ``SINGULAR_DISTANCE`` of ``x`` are
        skipped; a filter with none left is unchanged."""
        dx, dy = self.mean[:, 0, None] - positions[..., 0], self.mean[:, 1, None] - positions[..., 1]
        distances = np.hypot(dx, dy)
        usable = np.isfinite(ranges) & (distances > SINGULAR_DISTANCE)
        if not anywhere(usable):
            return
        # h h^T / v = (dx, dy)^T (dx, dy) / (d^2 v); h (z - d) / v = (dx, dy) (z - d) d / (d^2 v)
        weight = np.where(usable, 1.0 / np.where(usable, distances**2 * variances, 1.0), 0.0)
        pull = weight * np.where(usable, (ranges - distances) * distances, 0.0)
        gained_xx, gained_xy, gained_yy = (sequential_sum(weight * dx * dx, axis=1),
                                           sequential_sum(weight * dx * dy, axis=1),
                                           sequential_sum(weight * dy * dy, axis=1))
        information_x, information_y = sequential_sum(pull * dx, axis=1), sequential_sum(pull * dy, axis=1)
        prior = self.covariance
        determinant = prior[:, 0, 0] * prior[:, 1, 1] - prior[:, 0, 1] * prior[:, 0, 1]
        xx = prior[:, 1, 1] / determinant + gained_xx  # P+^-1, entry by entry
        xy = -prior[:, 0, 1] / determinant + gained_xy
        yy = prior[:, 0, 0] / determinant + gained_yy
        posterior = xx * yy - xy * xy
        covariance = np.empty_like(prior)
        covariance[:, 0, 0], covariance[:, 1, 1] = yy / posterior, xx / posterior
        covariance[:, 0, 1] = covariance[:, 1, 0] = -xy / posterior
        mean = self.mean + np.stack([covariance[:, 0, 0] * information_x + covariance[:, 0, 1] * information_y,
                                     covariance[:, 1, 0] * information_x + covariance[:, 1, 1] * information_y],
                                    axis=1)
        self.adopt(mean, covariance, np.asarray(usable.any(axis=1)))


def _products(left: FloatArray, right: FloatArray) -> FloatArray:
    """The matrix products ``L R`` of ``left`` (B, 2, 2) and ``right`` (B, 2, n),
    ``sum_c L[a, c] R[c, j]`` term by term (elementwise along the batch: no BLAS kernel chosen by shape)."""
    return left[:, :, 0, None] * right[:, None, 0, :] + left[:, :, 1, None] * right[:, None, 1, :]


def _ranges(x: FloatArray, positions: FloatArray) -> FloatArray:
    """Distances (m,) from the robots at ``positions`` (m, 2) to the point ``x`` (2,), metres."""
    return np.linalg.norm(x - positions, axis=1)


def _jacobian(x: FloatArray, positions: FloatArray) -> FloatArray:
    """``H``: rows ``(x - p_j)^T / ||x - p_j||`` (m, 2)."""
    offsets = x - positions
    return offsets / np.linalg.norm(offsets, axis=1, keepdims=True)


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
        jacobian = _jacobian(estimate, points)
        residual = measured - _ranges(estimate, points)
        estimate = estimate + np.linalg.lstsq(jacobian, residual, rcond=None)[0]
    jacobian = _jacobian(estimate, points)
    covariance = inflation * range_sigma**2 * np.linalg.inv(jacobian.T @ jacobian)
    return np.asarray(estimate, dtype=float), np.asarray(covariance, dtype=float)


# ---------------------------------------------------------------------------- configured estimators


def team_steady_variance(params: EstimationParams, robots: int) -> float:
    """The per-axis variance (m^2) the team's filters would settle to if each took every one of the
    ``robots`` ranges every step, the robots spread uniformly (:func:`world.target.steady_variance`
    of ``params.range_sigma`` and ``params.process_noise``)."""
    return steady_variance(robots, params.range_sigma, params.process_noise)


def prior_belief(
    params: EstimationParams, region: ConvexRegion, truth_at_start: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """The belief ``(mean, covariance)`` (metres, m^2) an estimator starts from: the configured
    prior, or for "trilateration" the uninformative one (see :class:`Estimators`)."""
    if params.prior == "trilateration":
        return region.chebyshev_centre[0].copy(), region.outer_diameter**2 * np.eye(2)
    mean = truth_at_start if params.prior == "truth" else params.prior
    return np.array(mean, dtype=float), params.prior_variance * np.eye(2)


class Estimators:
    """The beliefs about the target of a batch of decentralized robots or fusion centres.

    Every step: :meth:`measure` (predict, then update with the ranges each has); a decentralized robot
    that polled then :meth:`fuse` its neighbours' beliefs. After each of these every filter's own mean
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
    are like any other step. ``truths_at_start`` (B, 2), metres, is the true target of each filter's
    run at the start (the "truth" prior).
    """

    def __init__(self, params: EstimationParams, region: ConvexRegion, truths_at_start: ArrayLike) -> None:
        self.params = params
        self.region = region
        truths = np.asarray(truths_at_start, dtype=float).reshape(-1, 2)
        priors = [prior_belief(params, region, truth) for truth in truths]
        self.filters = RangeFilters([mean for mean, _ in priors], [covariance for _, covariance in priors],
                                    params.process_noise, params.range_sigma)
        self.keep_inside()
        self.started = False

    @property
    def belief(self) -> tuple[FloatArray, FloatArray]:
        """``(mean (B, 2), covariance (B, 2, 2))`` of the filters (metres, m^2), copies."""
        return self.filters.mean.copy(), self.filters.covariance.copy()

    @property
    def centre(self) -> FloatArray:
        """The estimates (B, 2), metres, robots steer about: the filters' means, inside by ``params.margin``."""
        return self.filters.mean.copy()

    def keep_inside(self, rows: NDArray[np.bool_] | None = None) -> None:
        """Pull each filter's mean (of the ``rows`` given, default all) ``params.margin`` metres inside
        the region if it is not that deep (covariance unchanged); a mean already inside is left
        exactly as it is."""
        mean = self.filters.mean
        # a mean clamped before sits on the margin up to rounding: inside, so clamping is idempotent
        outside = ~self.region.is_interior(mean, self.params.margin * (1.0 - MARGIN_ROUNDING))
        if rows is not None:
            outside &= rows
        if anywhere(outside):
            self.filters.mean = np.where(outside[:, None], self.region.clamp_interior(mean, self.params.margin), mean)

    def measure(self, positions: ArrayLike, ranges: ArrayLike, told: Told | None = None,
                late: tuple[FloatArray, FloatArray, FloatArray] | None = None) -> None:
        """Fold in one step's ranges (B, m) from robots at ``positions`` (B, m, 2) (NaN: no range).
        With the "trilateration" prior, the first step's ranges become the prior instead where they
        fix the target (see the class). Beliefs ``told`` by neighbours are fused by :meth:`fuse`
        between the prediction and the update, so the step's own ranges update the fused prior with
        their full Kalman weight."""
        points = np.asarray(positions, dtype=float).reshape(len(self.filters.mean), -1, 2)
        measured = np.asarray(ranges, dtype=float).reshape(len(self.filters.mean), -1)
        first, self.started = not self.started, True
        fixes = self._trilaterate(points, measured) if first and self.params.prior == "trilateration" else None
        self.filters.predict()
        if told is not None:
            self.fuse(told)
        if late is not None:
            self.filters.absorb(*late)
        self.filters.update(points, measured)
        if fixes is not None:
            self.filters.adopt(*fixes)  # a fix is the first step's estimate
        self.keep_inside()

    def _trilaterate(self, points: FloatArray, measured: FloatArray) -> tuple[FloatArray, FloatArray,
                                                                             NDArray[np.bool_]]:
        """The trilaterated beliefs ``(means, covariances)`` of the filters whose first ranges fix the
        target, and which those are (:func:`trilaterate`)."""
        fixed = np.zeros(len(measured), dtype=bool)
        means, covariances = self.belief
        for row in range(len(measured)):
            try:
                means[row], covariances[row] = trilaterate(points[row], measured[row], self.params.range_sigma)
            except NoFix:
                continue  # the uninformative prior stands, updated with the ranges there are
            fixed[row] = True
        return means, covariances, fixed

    def fuse(self, told: Told) -> None:
        """Covariance-intersect each filter's belief with the neighbours' ``told`` it and adopt the
        result; a filter told nothing is left as it is."""
        fusing: NDArray[np.bool_] = np.asarray(told.present.any(axis=1))
        if not anywhere(fusing):
            return
        # each fusing filter's own belief first, then what it was told (the rows told nothing left out)
        means = np.concatenate([self.filters.mean[fusing, None], told.means[fusing]], axis=1)
        covariances = np.concatenate([self.filters.covariance[fusing, None], told.covariances[fusing]], axis=1)
        present = np.concatenate([np.ones((len(means), 1), dtype=bool), told.present[fusing]], axis=1)
        if self.params.fusion != "ci":
            combine = intersect_in_order
        else:  # the same bits either way: floats for a few rows, arrays for many
            combine = intersect_rows if few(means) else intersect
        fused = combine(means, covariances, present, self.params.criterion)
        mean, covariance = self.belief
        mean[fusing], covariance[fusing] = fused.mean, fused.covariance
        self.filters.adopt(mean, covariance)
        self.keep_inside(fusing)


class Estimator:
    """One robot's or one fusion centre's belief: :class:`Estimators` as a batch of one, taking and
    giving single beliefs (mean (2,) metres, covariance (2, 2) m^2), as a process holds it."""

    def __init__(self, params: EstimationParams, region: ConvexRegion, truth_at_start: ArrayLike) -> None:
        self.batch = Estimators(params, region, np.asarray(truth_at_start, dtype=float)[None])

    @property
    def belief(self) -> tuple[FloatArray, FloatArray]:
        """``(mean, covariance)`` of the filter (metres, m^2)."""
        mean, covariance = self.batch.belief
        return mean[0], covariance[0]

    @property
    def centre(self) -> FloatArray:
        """The estimate (metres) the robot steers about (:attr:`Estimators.centre`)."""
        return self.batch.centre[0]

    def measure(self, positions: ArrayLike, ranges: ArrayLike,
                late: tuple[FloatArray, FloatArray, FloatArray] | None = None) -> None:
        """One step's ranges (m,) from robots at ``positions`` (m, 2), after the ``late`` ranges of
        other robots (origins (1, M, 2) metres, ranges (1, M) metres, variances (1, M) m^2)
        (:meth:`Estimators.measure`)."""
        self.batch.measure(np.asarray(positions, dtype=float)[None], np.asarray(ranges, dtype=float)[None],
                           late=late)

    def fuse(self, predecessor: Belief | None, successor: Belief | None) -> None:
        """Covariance-intersect the own belief with the ring neighbours' (either may be None) and adopt it."""
        self.batch.fuse(Told.by_sides(predecessor, successor))
