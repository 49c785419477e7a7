"""The posterior Cramér-Rao bound (PCRB) of range-only tracking (docs/algorithms.md section 19).

Tichavský, Muravchik and Nehorai, *Posterior Cramér-Rao bounds for discrete-time nonlinear
filtering*, IEEE Transactions on Signal Processing 46(5), 1998. For a linear motion model
``x(k) = F x(k-1) + w``, ``w ~ N(0, Q)`` (metres, ``Q`` in m^2 per step), and ranges
``z_j = ||x - p_j|| + v_j``, ``v_j ~ N(0, sigma^2)`` from robots at ``p_j``, the information matrix
(m^-2) of the target position obeys

    J(0) = P0^-1,    J(k) = (Q + F J(k-1)^-1 F^T)^-1 + E[H(k)^T R^-1 H(k)],

``H(k)``'s rows the unit vectors ``(x(k) - p_j)^T / ||x(k) - p_j||`` of the robots that measure at
step k and ``R = sigma^2 I``. Every estimator of ``x(k)`` from the ranges of steps ``1..k`` has a
mean squared error (m^2) of at least ``trace(J(k)^-1)``.

The expectation over the path is not taken: ``H`` is evaluated along one given (true) path and the
robots' positions of that run, a *path-conditional* bound, which is what a single run's error is
compared with. Everything here is 2x2 arithmetic written out component by component, elementwise
along any leading axes (a trial's bound does not depend on the batch it is computed in).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.geometry import FloatArray


def range_information(positions: ArrayLike, targets: ArrayLike, sigma: float,
                      max_range: float | None = None) -> FloatArray:
    """``H^T R^-1 H`` (m^-2, shape ``(..., 2, 2)``) of the ranges from robots at ``positions``
    (metres, ``(..., N, 2)``) to ``targets`` (metres, ``(..., 2)``) with noise ``sigma`` (metres):
    ``sum_j u_j u_j^T / sigma^2``, ``u_j`` the unit vector from robot j to the target. A robot beyond
    ``max_range`` (metres; None: unlimited) measures nothing and adds nothing, nor does one at the
    target (no bearing)."""
    positions, targets = np.asarray(positions, dtype=float), np.asarray(targets, dtype=float)
    information = np.zeros(targets.shape[:-1] + (2, 2))
    for robot in range(positions.shape[-2]):  # robot by robot: elementwise, whatever the batch
        dx = targets[..., 0] - positions[..., robot, 0]
        dy = targets[..., 1] - positions[..., robot, 1]
        distance = np.hypot(dx, dy)
        seen = (distance > 0) & (distance <= (np.inf if max_range is None else max_range))
        with np.errstate(invalid="ignore", divide="ignore"):
            ux, uy = np.where(seen, dx / distance, 0.0), np.where(seen, dy / distance, 0.0)
        information[..., 0, 0] += ux * ux / sigma**2
        information[..., 0, 1] += ux * uy / sigma**2
        information[..., 1, 1] += uy * uy / sigma**2
    information[..., 1, 0] = information[..., 0, 1]
    return information


def inverse(matrix: ArrayLike) -> FloatArray:
    """The inverse of symmetric 2x2 matrices (shape ``(..., 2, 2)``), by the adjugate."""
    matrix = np.asarray(matrix, dtype=float)
    a, b, c = matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 1, 1]
    determinant = a * c - b * b
    result = np.empty(matrix.shape)
    result[..., 0, 0], result[..., 1, 1] = c / determinant, a / determinant
    result[..., 0, 1] = result[..., 1, 0] = -b / determinant
    return result


def congruence(transition: ArrayLike, matrix: FloatArray) -> FloatArray:
    """``F S F^T`` of a constant 2x2 ``transition`` F and symmetric 2x2 matrices S (``(..., 2, 2)``)."""
    f = np.asarray(transition, dtype=float)
    a, b, c = matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 1, 1]
    rows = [(f[i, 0] * a + f[i, 1] * b, f[i, 0] * b + f[i, 1] * c) for i in (0, 1)]  # rows of F S
    result = np.empty(matrix.shape)
    for i in (0, 1):
        for j in (0, 1):
            result[..., i, j] = rows[i][0] * f[j, 0] + rows[i][1] * f[j, 1]
    return result


def posterior_information(measured: ArrayLike, prior_covariance: ArrayLike, transition: ArrayLike,
                          process_noise: ArrayLike) -> FloatArray:
    """``J(k)`` (m^-2) for k = 1..K of the recursion in the module docstring: ``measured`` holds
    ``E[H(k)^T R^-1 H(k)]`` (m^-2, shape ``(K, ..., 2, 2)``, steps on axis 0), ``prior_covariance``
    ``P0`` (m^2, 2x2: ``J(0) = P0^-1``), ``transition`` F (2x2) and ``process_noise`` Q (m^2 per step,
    2x2). Returns the shape of ``measured``."""
    measured = np.asarray(measured, dtype=float)
    noise = np.asarray(process_noise, dtype=float)
    covariance = np.broadcast_to(np.asarray(prior_covariance, dtype=float), measured.shape[1:])  # J(0)^-1
    result = np.empty(measured.shape)
    for k in range(len(measured)):
        result[k] = inverse(congruence(transition, covariance) + noise) + measured[k]
        covariance = inverse(result[k])
    return result


def random_walk_bound(positions: ArrayLike, targets: ArrayLike, sigma: float, step_variance: float,
                      prior_variance: float, max_range: float | None = None) -> FloatArray:
    """The PCRB on the mean squared error (m^2), ``trace(J(k)^-1)``, of a random-walk target
    (``F = I``, ``Q = step_variance I``, m^2 per step) tracked from ranges of noise ``sigma`` (metres)
    by robots at ``positions`` (metres, ``(K, ..., N, 2)``, steps on axis 0) along its path
    ``targets`` (metres, ``(K, ..., 2)``), from the prior ``P0 = prior_variance I`` (m^2); robots
    beyond ``max_range`` (metres) measure nothing. Shape ``(K, ...)``: a path-conditional bound."""
    information = posterior_information(range_information(positions, targets, sigma, max_range),
                                        prior_variance * np.eye(2), np.eye(2), step_variance * np.eye(2))
    covariance = inverse(information)
    return covariance[..., 0, 0] + covariance[..., 1, 1]
