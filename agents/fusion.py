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

Everything here works on a batch of fusions at once (:func:`intersect`: ``B`` rows of up to ``k``
estimates, a mask saying which are present), elementwise along the batch, so a row's result does
not depend on the other rows: a robot process fusing alone (a batch of one) gets bit for bit what
the engine gets for that robot in a batch of every robot of every trial.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from itertools import combinations
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.geometry import FloatArray
from ringtrack.world.params import Criterion

TIE_TOLERANCE = 1e-12  # relative: candidates this close to the best are equally optimal
FEASIBLE = -1e-12  # a face's stationary weights at least this are on the simplex (clipped to 0)
DEGENERATE = 1e-12  # relative determinant below which a face's system is singular
ACCUMULATED_TERMS = 100  # elements per term up to which sequential_sum takes numpy's running sum


@dataclass(frozen=True)
class Fused:
    """Fused estimates: ``mean`` (..., 2) metres, ``covariance`` (..., 2, 2) m^2 and the CI
    ``weights`` (..., k), one per input (0 for an absent one)."""

    mean: FloatArray
    covariance: FloatArray
    weights: FloatArray


def _inverse_entries(xx: FloatArray, xy: FloatArray, yy: FloatArray) -> FloatArray:
    """The entries ``(xx, xy, yy)`` of the inverses of the symmetric 2x2 matrices with entries ``xx``,
    ``xy``, ``yy`` (any one shape ``S``), by the adjugate, as one array (3,) + S."""
    return np.array([yy, -xy, xx]) / (xx * yy - xy * xy)


def intersect(means: ArrayLike, covariances: ArrayLike, present: ArrayLike | None = None,
              criterion: Criterion = "trace") -> Fused:
    """Fuse each row of a batch by optimal CI: ``means`` (B, k, 2), ``covariances`` (B, k, 2, 2),
    symmetric positive definite where ``present`` (B, k; default all) says an estimate is there.
    The weights minimise ``tr P_c`` ("trace") or ``det P_c`` ("det") exactly over the present
    estimates; every row needs at least one."""
    means = np.asarray(means, dtype=float)
    rows, count = means.shape[:2]
    present = np.ones((rows, count), dtype=bool) if present is None else np.asarray(present, dtype=bool)
    information = _information(np.where(present[..., None, None], np.asarray(covariances, dtype=float), identity(2)))
    if count == 1:
        return _intersect(means, information, np.ones((1, rows)))
    return _intersect(means, information, _optimal_weights(information, present.T, criterion))


def _information(covariances: FloatArray) -> FloatArray:
    """The entries ``(xx, xy, yy)`` (3, k, B) of the information matrices ``P_k^{-1}`` of
    ``covariances`` (B, k, 2, 2), the batch last (each array operation then runs along whole rows of
    the batch)."""
    entries = covariances.transpose(2, 3, 1, 0)  # (2, 2, k, B)
    return _inverse_entries(entries[0, 0], 0.5 * (entries[0, 1] + entries[1, 0]), entries[1, 1])


def _optimal_weights(information: FloatArray, present: NDArray[np.bool_], criterion: Criterion) -> FloatArray:
    """The optimal CI weights (k, B) of each row of the batch, from the entries of the information
    matrices (3, k, B) of its ``present`` (k, B) estimates."""
    count, rows = present.shape
    traces = information[0] + information[2]
    determinants = _determinant_form(information, traces)
    # singular faces and fused information are found and ruled out on the way (their divisions by
    # zero are expected)
    with np.errstate(divide="ignore", invalid="ignore"):
        face_weights, face_feasible = _face_candidates(traces, determinants, criterion, present)
        candidates = np.empty((count, count + face_weights.shape[1], rows))  # (k, C, B): the vertices, then the faces'
        candidates[:, :count], candidates[:, count:] = identity(count)[..., None], face_weights
        feasible = np.concatenate([present, face_feasible], axis=0)
        values = np.where(feasible, _objective(candidates, traces, determinants, criterion), np.inf)
    # Ties (equal covariances make every weight optimal): the objective is convex in the weights, so
    # the mean of the tied optima is optimal too, and it does not depend on the order of the inputs.
    chosen = values <= np.minimum.reduce(values, axis=0, keepdims=True) * (1.0 + TIE_TOLERANCE)
    total = sequential_sum(np.where(chosen, candidates, 0.0), axis=1)
    return total / np.add.reduce(chosen, axis=0)


def sequential_sum(values: FloatArray, axis: int) -> FloatArray:
    """The sum along ``axis`` added strictly in order, ``((v_0 + v_1) + v_2) + ...``, so that a row's
    sum never depends on the shape of its batch (numpy's ``sum`` may pair terms differently). Small
    arrays take the last of numpy's running sums (one call), larger ones add term by term (numpy's
    running sum along an inner axis pays per element): the same additions either way."""
    values = np.asarray(values)
    count = values.shape[axis]
    index: list[slice | int] = [slice(None)] * values.ndim
    if count > 2 and values.size <= ACCUMULATED_TERMS * count:
        index[axis] = -1
        return np.add.accumulate(values, axis=axis)[tuple(index)]
    index[axis] = 0
    total = values[tuple(index)]
    for term in range(1, count):
        index[axis] = term
        total = total + values[tuple(index)]
    return total


def solve_small(matrices: FloatArray, right: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(X, det)`` with ``matrices X = right`` for square ``matrices`` (k, k, ...) and ``right``
    (k, r, ...), the batch on the last axes, and each matrix's determinant (...); for k <= 3 by the
    adjugate, component by component (elementwise along the batch, and without LAPACK's cost per
    call), else by LAPACK."""
    size = matrices.shape[0]
    if size > 3:
        batch_first = np.moveaxis(matrices, (0, 1), (-2, -1))
        determinant: FloatArray = np.asarray(np.linalg.det(batch_first), dtype=float)
        safe = np.where(determinant[..., None, None] != 0.0, batch_first, np.eye(size))
        solution = np.linalg.solve(safe, np.moveaxis(right, (0, 1), (-2, -1)))
        return np.asarray(np.moveaxis(solution, (-2, -1), (0, 1)), dtype=float), determinant
    if size == 1:
        stacked = np.ones(matrices.shape)
        determinant = matrices[0, 0]
    elif size == 2:
        m = [[matrices[row, column] for column in range(size)] for row in range(size)]
        stacked = np.stack([m[1][1], -m[0][1], -m[1][0], m[0][0]]).reshape(matrices.shape)
        determinant = m[0][0] * m[1][1] - m[0][1] * m[1][0]
    else:
        stacked, determinant = _adjugate_3x3(matrices)
    with np.errstate(divide="ignore", invalid="ignore"):
        solution = sequential_sum(stacked[:, :, None] * right[None], axis=1)  # adj(M) right
        return solution / determinant, determinant


# The adjugate of a 3x3 matrix (entries a..i row by row, flat indices 0..8), entry by entry in row
# order, each ``x y - z w``: the flat indices of x, y, z and w (the rows of this table, end to end).
_ADJUGATE_3X3 = np.array([[4, 2, 1, 5, 0, 2, 3, 1, 0],   # e c b f a c d b a
                          [8, 7, 5, 6, 8, 3, 7, 6, 4],   # i h f g i d h g e
                          [5, 1, 2, 3, 2, 0, 4, 0, 1],   # f b c d c a e a b
                          [7, 8, 4, 8, 6, 5, 6, 7, 3]]).ravel()  # h i e i g f g h d


def _adjugate_3x3(matrices: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The adjugates (3, 3, ...) and determinants (...) of 3x3 ``matrices`` (3, 3, ...), by cofactors:
    every entry ``x y - z w`` and the determinant ``(a A + b B) + c C`` along the first row, computed
    elementwise (one gather of all the factors, then three array operations)."""
    flat = matrices.reshape((9,) + matrices.shape[2:])
    factors = flat[_ADJUGATE_3X3]
    adjugate = factors[:9] * factors[9:18] - factors[18:27] * factors[27:]
    determinant = flat[0] * adjugate[0] + flat[1] * adjugate[3] + flat[2] * adjugate[6]
    return adjugate.reshape(matrices.shape), determinant


@lru_cache(maxsize=16)
def identity(size: int) -> FloatArray:
    """The ``size`` x ``size`` identity, read-only (shared)."""
    identity = np.eye(size)
    identity.setflags(write=False)
    return identity


class Faces(NamedTuple):
    """The faces of the simplex of ``k`` weights with two or more vertices, read-only: which weights
    each holds (``across``, (k, F, 1)) and which not (``outside``), their sizes (F, 1) and which
    entries of a k x k system each spans (``inside``, (k, k, F, 1)); the trailing axes broadcast
    along a batch."""

    across: NDArray[np.bool_]
    outside: NDArray[np.bool_]
    sizes: NDArray[np.int64]
    inside: NDArray[np.bool_]


@lru_cache(maxsize=16)
def _faces(count: int) -> Faces:
    """The :class:`Faces` of the simplex of ``count`` weights."""
    faces = [face for size in range(2, count + 1) for face in combinations(range(count), size)]
    members = np.zeros((count, len(faces)), dtype=bool)
    for index, face in enumerate(faces):
        members[list(face), index] = True
    shared = Faces(members[:, :, None], ~members[:, :, None], members.sum(axis=0)[:, None],
                   (members[:, None] & members[None])[..., None])
    for array in shared:
        array.setflags(write=False)
    return shared


def covariance_intersection(means: ArrayLike, covariances: ArrayLike, criterion: Criterion = "trace") -> Fused:
    """Fuse ``k >= 1`` estimates: ``means`` of shape (k, 2), ``covariances`` (k, 2, 2), symmetric
    positive definite, by optimal CI (:func:`intersect` with a batch of one)."""
    fused = intersect(np.asarray(means, dtype=float)[None], np.asarray(covariances, dtype=float)[None],
                      criterion=criterion)
    return Fused(fused.mean[0], fused.covariance[0], fused.weights[0])


def intersect_at(means: ArrayLike, covariances: ArrayLike, weights: ArrayLike) -> Fused:
    """The CI of ``k`` estimates at given ``weights`` (k,) on the simplex, optimal or not:
    ``P_c = (sum_k w_k P_k^{-1})^{-1}``, ``x_c = P_c sum_k w_k P_k^{-1} x_k`` (P_c symmetric).
    :func:`covariance_intersection` is this at its optimal weights."""
    information = _information(np.asarray(covariances, dtype=float)[None])
    fused = _intersect(np.asarray(means, dtype=float)[None], information, np.asarray(weights, dtype=float)[:, None])
    return Fused(fused.mean[0], fused.covariance[0], fused.weights[0])


def sequential_intersection(means: ArrayLike, covariances: ArrayLike, criterion: Criterion = "trace") -> Fused:
    """Pairwise CI in order, ``((x_0 + x_1) + x_2) + ...`` (a feasible point of the joint problem,
    so never better than :func:`covariance_intersection`)."""
    means = np.asarray(means, dtype=float)
    covariances = np.asarray(covariances, dtype=float)
    fused = intersect_in_order(means[None], covariances[None], np.ones((1, len(means)), dtype=bool), criterion)
    return Fused(fused.mean[0], fused.covariance[0], fused.weights[0] if len(means) > 1 else np.ones(1))


def intersect_in_order(means: FloatArray, covariances: FloatArray, present: NDArray[np.bool_],
                       criterion: Criterion = "trace") -> Fused:
    """:func:`sequential_intersection` of each row of a batch (shapes as :func:`intersect`; the first
    estimate of every row present): the present estimates fused pairwise in order. ``weights`` are
    those of the last pairwise fusion of each row."""
    mean, covariance = means[:, 0], covariances[:, 0]
    weights = np.zeros((len(means), 2))
    weights[:, 0] = 1.0
    for index in range(1, means.shape[1]):
        here = present[:, index]
        if here.any():
            pair = intersect(np.stack([mean, means[:, index]], axis=1),
                             np.stack([covariance, covariances[:, index]], axis=1),
                             np.stack([np.ones(len(means), dtype=bool), here], axis=1), criterion)
            mean = np.where(here[:, None], pair.mean, mean)
            covariance = np.where(here[:, None, None], pair.covariance, covariance)
            weights = np.where(here[:, None], pair.weights, weights)
    return Fused(mean, covariance, weights)


def _intersect(means: FloatArray, information: FloatArray, weights: FloatArray) -> Fused:
    """The CI of every row at its ``weights`` (k, B), from the means (B, k, 2) and the entries of the
    information matrices ``P_k^{-1}`` (3, k, B); absent estimates have weight 0. Every product is
    written out entry by entry (no BLAS: the same bits whatever the batch)."""
    fused = sequential_sum(weights * information, axis=1)  # (xx, xy, yy) of sum w_k P_k^{-1}, (3, B)
    coordinates = means.transpose(2, 1, 0)  # (2, k, B)
    informed = information[:2] * coordinates[0] + information[1:] * coordinates[1]  # P_k^{-1} x_k, (2, k, B)
    summed = sequential_sum(weights * informed, axis=1)  # (2, B)
    covariance = _inverse_entries(*fused)  # (xx, xy, yy) of P_c, (3, B)
    mean = covariance[:2] * summed[0] + covariance[1:] * summed[1]  # P_c sum w_k P_k^{-1} x_k, (2, B)
    return Fused(mean=mean.T, covariance=covariance[[0, 1, 1, 2]].T.reshape(-1, 2, 2), weights=weights.T)


def _determinant_form(information: FloatArray, traces: FloatArray) -> FloatArray:
    """``D`` (k, k, B): ``det(sum_k w_k I_k) = w^T D w`` (the module docstring), from the entries of
    the information matrices (3, k, B) and their traces (k, B)."""
    products = information[:, :, None] * information[:, None]  # (3, k, k, B)
    form = 0.5 * (traces[:, None] * traces[None] - (products[0] + 2.0 * products[1] + products[2]))
    count = len(traces)
    diagonal = form.reshape((count * count,) + traces.shape[1:])[:: count + 1]  # form is fresh: a view
    diagonal[...] = information[0] * information[2] - information[1] * information[1]
    return form


def _objective(weights: FloatArray, traces: FloatArray, determinants: FloatArray, criterion: Criterion) -> FloatArray:
    """``tr P_c`` or ``det P_c`` (C, B) at each candidate's ``weights`` (k, C, B) (inf where the fused
    information is singular), from the traces (k, B) and the determinant form (k, k, B)."""
    form = sequential_sum(determinants[:, :, None] * weights[None], axis=1)  # D w, (k, C, B)
    determinant = sequential_sum(weights * form, axis=0)
    trace = sequential_sum(traces[:, None] * weights, axis=0)
    value = trace / determinant if criterion == "trace" else 1.0 / determinant
    return np.where(determinant > 0.0, value, np.inf)


def _face_candidates(traces: FloatArray, determinants: FloatArray, criterion: Criterion,
                     present: NDArray[np.bool_]) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Stationary points of the objective restricted to each face of two or more present estimates
    (other weights 0), from the traces (k, B), the determinant form (k, k, B) and which estimates are
    ``present`` (k, B): the candidates' ``weights`` (k, C, B) and whether each is ``feasible`` (C, B);
    one candidate per face for "det", one per root (two) for "trace", face by face. Each face's
    system is solved as a k x k system with the identity outside the face, so all faces are one
    batched solve. Singular faces divide by zero: call under ``np.errstate`` (as
    :func:`_optimal_weights` does)."""
    count, rows = traces.shape
    across, outside, sizes, inside = _faces(count)
    on_face = np.logical_and.reduce(present[:, None] | outside, axis=0)  # (F, B)
    sub = np.where(inside, determinants[:, :, None], identity(count)[:, :, None, None])  # (k, k, F, B)
    scale = np.maximum.reduce(np.where(inside, np.abs(sub), 0.0), axis=(0, 1))
    right = np.empty((count, 2, across.shape[1], rows))  # (k, 2, F, B): the face's traces, and its ones
    right[:, 0], right[:, 1] = np.where(across, traces[:, None], 0.0), across
    face_traces = right[:, 0]
    solved, determinant = solve_small(sub, right)
    # a degenerate face's optimum lies on a smaller face
    usable = on_face & (np.abs(determinant) >= DEGENERATE * np.maximum(scale, 1e-300) ** sizes)
    solved = np.where(usable, solved, 0.0)
    a, b = solved[:, 0], solved[:, 1]  # (k, F, B)
    a_sum, b_sum = sequential_sum(solved, axis=0)
    if criterion == "det":
        local, solvable = (b / b_sum)[:, :, None], (usable & (b_sum != 0))[:, None]
    else:
        traced_a, traced_b = sequential_sum(face_traces[:, None] * solved, axis=0)  # t . a, t . b
        roots, found = _positive_roots(b_sum, a_sum - traced_b, -traced_a)  # (F, 2, B)
        total = a_sum[:, None] + roots * b_sum[:, None]
        local = (a[:, :, None] + roots * b[:, :, None]) / total
        solvable = usable[:, None] & found & (total != 0)
    # local (k, F, R, B): R candidates per face, 0 off the face
    feasible = solvable & np.logical_and.reduce(local >= FEASIBLE, axis=0)
    clipped = np.maximum(np.where(feasible, local, across[..., None]), 0.0)
    weights = clipped / sequential_sum(clipped, axis=0)
    return weights.reshape(count, -1, rows), feasible.reshape(-1, rows)


def _positive_roots(quadratic: FloatArray, linear: FloatArray, constant: FloatArray) -> tuple[FloatArray,
                                                                                           NDArray[np.bool_]]:
    """The distinct positive real roots ``L`` of ``quadratic L^2 + linear L + constant = 0``
    elementwise (coefficients (F, B)) (a vanishing leading coefficient leaves the linear equation), in the
    cancellation-free form ``q = -(linear + sign(linear) sqrt(disc)) / 2``, roots ``q / quadratic``
    and ``constant / q``: ``(roots, found)`` (F, 2, B), two slots per equation,
    the smaller root first (a lone root in the first slot)."""
    discriminant = linear * linear - 4.0 * quadratic * constant
    q = -0.5 * (linear + np.copysign(np.sqrt(np.maximum(discriminant, 0.0)), linear))
    linear_only = quadratic == 0.0
    first = np.where(linear_only, -constant / linear, q / quadratic)
    real = discriminant >= 0.0
    first_found = np.where(linear_only, linear != 0.0, real) & (first > 0.0)
    second = constant / q
    second_found = ~linear_only & real & (q != 0.0) & (second > 0.0) & ~(first_found & (second == first))
    # a root not found is +inf here, so the smaller found root comes first
    first, second = np.where(first_found, first, np.inf), np.where(second_found, second, np.inf)
    roots = np.array([np.minimum(first, second), np.maximum(first, second)])
    found = np.array([first_found | second_found, first_found & second_found])
    return roots.swapaxes(0, 1), found.swapaxes(0, 1)
