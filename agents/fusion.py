"""Covariance intersection of 2-D Gaussian estimates (docs/algorithms.md section 8).

Covariance intersection (CI; Julier & Uhlmann 1997) fuses estimates ``(x_k, P_k)`` whose cross
correlations are unknown:

    P_c^{-1} = sum_k w_k P_k^{-1},    x_c = P_c sum_k w_k P_k^{-1} x_k,    w on the simplex,

with the weights ``w`` minimising ``tr P_c`` (default) or ``det P_c`` (:func:`intersect_at` applies
the formulas at any given weights). Positions in metres, covariances in m^2.

The weights come in closed form for any number of 2-D estimates (Reinhardt, Noack & Hanebeck 2012
treat two). With information matrices ``I_k = P_k^{-1}`` and ``M(w) = sum_k w_k I_k``:

* ``tr M(w) = t . w`` with ``t_k = tr I_k`` (linear) and, because ``det(A + B) = det A + det B +
  tr A tr B - tr(AB)`` for 2x2 matrices, ``det M(w) = w^T D w`` with ``D_kk = det I_k`` and
  ``D_jk = (tr I_j tr I_k - tr(I_j I_k)) / 2`` (a quadratic form);
* trace: minimise ``f = tr M^{-1} = (t . w) / (w^T D w)``. ``f`` is homogeneous of degree -1, so at a
  stationary point on the plane ``sum w = 1`` the Lagrange multiplier is ``-f`` and
  ``D w = s (t + L 1)`` with ``L = t . w`` and ``s = 1 / (sum a + L sum b)``, ``a = D^{-1} t``,
  ``b = D^{-1} 1``; then ``L`` solves ``(sum b) L^2 + (sum a - t . b) L - t . a = 0`` and
  ``w = s (a + L b)``;
* determinant: maximise ``w^T D w``; stationary where ``D w = lambda 1``, ``w = b / sum b``.

Every face of the simplex (each non-empty subset of the estimates) is solved this way, infeasible
candidates (a negative weight) are dropped, and the best remaining candidate wins (the mean of the
best ones when several tie, which keeps CI symmetric in its inputs); the vertices are the single
estimates. With two estimates this is the two-estimate closed form of that paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.geometry import FloatArray
from ringtrack.world.params import Criterion

TIE_TOLERANCE = 1e-12  # relative: candidates this close to the best are equally optimal


@dataclass(frozen=True)
class Fused:
    """A fused estimate: ``mean`` (2,), ``covariance`` (2, 2) and the CI ``weights`` (one per input)."""

    mean: FloatArray
    covariance: FloatArray
    weights: FloatArray


def covariance_intersection(
    means: ArrayLike, covariances: ArrayLike, criterion: Criterion = "trace"
) -> Fused:
    """Fuse ``k >= 1`` estimates: ``means`` of shape (k, 2), ``covariances`` (k, 2, 2), symmetric
    positive definite. The weights minimise ``tr P_c`` ("trace") or ``det P_c`` ("det") exactly."""
    means = np.asarray(means, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    information = np.linalg.inv(covariances)
    traces = np.trace(information, axis1=1, axis2=2)
    products = np.einsum("jab,kba->jk", information, information)
    determinants = 0.5 * (np.outer(traces, traces) - products)
    np.fill_diagonal(determinants, np.linalg.det(information))
    count = len(means)
    candidates = [
        weights
        for size in range(1, count + 1)
        for face in combinations(range(count), size)
        for weights in _face_candidates(np.array(face), traces, determinants, criterion, count)
    ]
    values = np.array([_objective(weights, traces, determinants, criterion) for weights in candidates])
    best_value = values.min()
    # Ties (equal covariances make every weight optimal): the objective is convex in the weights, so
    # the mean of the tied optima is optimal too, and it does not depend on the order of the inputs.
    tied = [weights for weights, value in zip(candidates, values, strict=True)
            if value <= best_value * (1.0 + TIE_TOLERANCE)]
    return _intersect(means, information, np.mean(tied, axis=0))


def intersect_at(means: ArrayLike, covariances: ArrayLike, weights: ArrayLike) -> Fused:
    """The CI of ``k`` estimates at given ``weights`` (k,) on the simplex, optimal or not:
    ``P_c = (sum_k w_k P_k^{-1})^{-1}``, ``x_c = P_c sum_k w_k P_k^{-1} x_k`` (P_c symmetrised).
    :func:`covariance_intersection` is this at its optimal weights."""
    information = np.linalg.inv(np.asarray(covariances, dtype=float))
    return _intersect(np.asarray(means, dtype=float), information, np.asarray(weights, dtype=float))


def _intersect(means: FloatArray, information: FloatArray, weights: FloatArray) -> Fused:
    """:func:`intersect_at` from the information matrices ``P_k^{-1}`` (k, 2, 2)."""
    covariance = np.linalg.inv(np.einsum("k,kab->ab", weights, information))
    covariance = 0.5 * (covariance + covariance.T)
    mean = covariance @ np.einsum("k,kab,kb->a", weights, information, means)
    return Fused(mean=mean, covariance=covariance, weights=weights)


def sequential_intersection(means: ArrayLike, covariances: ArrayLike, criterion: Criterion = "trace") -> Fused:
    """Pairwise CI in order, ``((x_0 + x_1) + x_2) + ...`` (a feasible point of the joint problem,
    so never better than :func:`covariance_intersection`)."""
    means = np.asarray(means, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    fused = Fused(means[0], covariances[0], np.ones(1))
    for mean, covariance in zip(means[1:], covariances[1:], strict=True):
        fused = covariance_intersection([fused.mean, mean], [fused.covariance, covariance], criterion)
    return fused


def _objective(weights: FloatArray, traces: FloatArray, determinants: FloatArray, criterion: Criterion) -> float:
    """``tr P_c`` or ``det P_c`` for ``weights`` (inf where the fused information is singular)."""
    determinant = float(weights @ determinants @ weights)
    if determinant <= 0.0:
        return np.inf
    return float(traces @ weights) / determinant if criterion == "trace" else 1.0 / determinant


def _face_candidates(
    face: NDArray[np.int64], traces: FloatArray, determinants: FloatArray, criterion: Criterion, count: int
) -> list[FloatArray]:
    """Stationary points of the objective restricted to the weights in ``face`` (others 0)."""
    if len(face) == 1:
        weights = np.zeros(count)
        weights[face[0]] = 1.0
        return [weights]
    sub = determinants[face[:, None], face]
    if abs(np.linalg.det(sub)) < 1e-12 * max(np.abs(sub).max(), 1e-300) ** len(face):
        return []  # degenerate face: its optimum lies on a smaller face
    face_traces = traces[face]
    a, b = np.linalg.solve(sub, np.stack([face_traces, np.ones(len(face))], axis=1)).T
    if criterion == "det":
        solutions = [b / b.sum()] if b.sum() != 0 else []
    else:
        solutions = []
        for root in _positive_roots(b.sum(), a.sum() - face_traces @ b, -(face_traces @ a)):
            scale = a.sum() + root * b.sum()
            if scale != 0:
                solutions.append((a + root * b) / scale)
    candidates = []
    for local in solutions:
        if np.all(local >= -1e-12):
            weights = np.zeros(count)
            weights[face] = np.clip(local, 0.0, None)
            weights /= weights.sum()
            candidates.append(weights)
    return candidates


def _positive_roots(quadratic: float, linear: float, constant: float) -> list[float]:
    """The distinct positive real roots ``L`` of ``quadratic L^2 + linear L + constant = 0`` (a
    vanishing leading coefficient leaves the linear equation), in the cancellation-free form
    ``q = -(linear + sign(linear) sqrt(disc)) / 2``, roots ``q / quadratic`` and ``constant / q``."""
    if quadratic == 0.0:
        roots = [-constant / linear] if linear != 0.0 else []
    else:
        discriminant = linear * linear - 4.0 * quadratic * constant
        if discriminant < 0.0:
            return []
        q = -0.5 * (linear + math.copysign(math.sqrt(discriminant), linear))
        roots = [q / quadratic] + ([constant / q] if q != 0.0 else [])
    return sorted({float(root) for root in roots if root > 0.0})
