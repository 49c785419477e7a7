"""Covariance intersection of a few rows of three estimates in Python floats, bit for bit the
batched :func:`ringtrack.agents.fusion.intersect`.

The batched CI solves every row with about 120 array operations whatever the batch's size; on the
one or two rows a robot or a small team fuses in a step, numpy's cost per call is nearly all of it.
:func:`intersect_rows` runs the batched arithmetic on each row of three estimates (a robot's own
and its two ring neighbours', some absent) in Python floats: the same operations on the same
operands in the same order (IEEE-754 addition, subtraction, multiplication, division and square
root round alike in numpy and in Python; products ``x y`` and ``y x`` are equal), the same
candidates in the same order, so the result is the batched one to the last bit, which
``tests/test_fusion.py`` checks byte for byte over random batches. The power that scales the
degeneracy test, which numpy computes its own way, is left to numpy.

Positions in metres, covariances in m^2.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ringtrack.agents.fusion import DEGENERATE, FEASIBLE, TIE_TOLERANCE, Fused
from ringtrack.world.geometry import FloatArray
from ringtrack.world.params import Criterion

ESTIMATES = 3  # per row: a robot's own and its two neighbours'
FEW_ROWS = 3  # batches of at most this many rows are fused here (the arrays are as fast at about 4)
INF = math.inf
FACES = ((0, 1), (0, 2), (1, 2), (0, 1, 2))  # the batched code's faces of two or more weights, in order
FACE_SIZES = np.array([2, 2, 2, 3])
TIED = 1.0 + TIE_TOLERANCE

Entries = tuple[float, float, float]  # (xx, xy, yy) of a symmetric 2x2 matrix


def few(means: FloatArray) -> bool:
    """Whether the batch ``means`` (B, k, 2) is one :func:`intersect_rows` fuses faster."""
    rows, count = means.shape[:2]
    return rows <= FEW_ROWS and count == ESTIMATES


def intersect_rows(means: FloatArray, covariances: FloatArray, present: NDArray[np.bool_],
                   criterion: Criterion = "trace") -> Fused:
    """:func:`ringtrack.agents.fusion.intersect` of each row of three estimates, in floats: ``means``
    (B, 3, 2) metres, ``covariances`` (B, 3, 2, 2) m^2, ``present`` (B, 3); the same bits."""
    if means.shape[1] != ESTIMATES:
        raise ValueError(f"intersect_rows fuses rows of {ESTIMATES} estimates, got {means.shape[1]}")
    rows_present = present.tolist()
    absent = (1.0, -0.0, 1.0)  # the batched code's inverse of the identity standing in for an absent estimate
    informations = [[_information(matrix) if here else absent for matrix, here in zip(row, row_present, strict=True)]
                    for row, row_present in zip(covariances.tolist(), rows_present, strict=True)]
    traces = [_traces(information) for information in informations]
    forms = [_determinant_form(information, row_traces) for information, row_traces in zip(informations, traces,
                                                                                             strict=True)]
    powers = np.power(np.maximum([[_scale(form, face) for face in FACES] for form in forms], 1e-300),
                      FACE_SIZES).tolist()
    weights = [_optimal_weights(*row, criterion) for row in zip(traces, forms, rows_present, powers, strict=True)]
    fused = [_fuse(row_means, information, row_weights)
             for row_means, information, row_weights in zip(means.tolist(), informations, weights, strict=True)]
    return Fused(mean=np.array([mean for mean, _ in fused]),
                 covariance=np.array([covariance for _, covariance in fused]), weights=np.array(weights))


def _quotient(numerator: float, denominator: float) -> float:
    """``numerator / denominator`` where the denominator is 0: numpy's signed infinity or NaN
    (the batched code divides by zero where the result is then ruled out)."""
    if numerator == 0.0 or numerator != numerator:
        return math.nan
    return math.copysign(INF, numerator) * math.copysign(1.0, denominator)


def _information(covariance: list[list[float]]) -> Entries:
    """The entries of a covariance's inverse, its off-diagonal the mean of the two."""
    (xx, xy_upper), (xy_lower, yy) = covariance
    return _inverse(xx, 0.5 * (xy_upper + xy_lower), yy)


def _inverse(xx: float, xy: float, yy: float) -> Entries:
    """The inverse's entries by the adjugate: ``(yy, -xy, xx) / (xx yy - xy^2)``."""
    determinant = xx * yy - xy * xy
    if not determinant:
        return _quotient(yy, determinant), _quotient(-xy, determinant), _quotient(xx, determinant)
    return yy / determinant, -xy / determinant, xx / determinant


def _traces(information: list[Entries]) -> list[float]:
    """``tr I_k`` of each estimate's information."""
    return [xx + yy for xx, _, yy in information]


def _determinant_form(information: list[Entries], traces: list[float]) -> list[list[float]]:
    """``D`` with ``det(sum_k w_k I_k) = w^T D w`` (symmetric, exactly: each entry's products commute)."""
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = information
    t0, t1, t2 = traces
    d01 = 0.5 * (t0 * t1 - (a0 * a1 + 2.0 * (b0 * b1) + c0 * c1))
    d02 = 0.5 * (t0 * t2 - (a0 * a2 + 2.0 * (b0 * b2) + c0 * c2))
    d12 = 0.5 * (t1 * t2 - (a1 * a2 + 2.0 * (b1 * b2) + c1 * c2))
    return [[a0 * c0 - b0 * b0, d01, d02], [d01, a1 * c1 - b1 * b1, d12], [d02, d12, a2 * c2 - b2 * b2]]


def _scale(form: list[list[float]], face: tuple[int, ...]) -> float:
    """The largest magnitude of the face's entries of ``D`` (NaN if one is, as numpy's maximum)."""
    magnitudes = [abs(form[row][column]) for row in face for column in face]
    if any(magnitude != magnitude for magnitude in magnitudes):
        return math.nan
    return max(magnitudes)


def _face_system(form: list[list[float]], face: tuple[int, ...]) -> tuple[float, ...]:
    """The face's 3x3 system row by row: ``D`` on the face's entries, the identity elsewhere."""
    (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = form
    if face == (0, 1):
        return d00, d01, 0.0, d10, d11, 0.0, 0.0, 0.0, 1.0
    if face == (0, 2):
        return d00, 0.0, d02, 0.0, 1.0, 0.0, d20, 0.0, d22
    if face == (1, 2):
        return 1.0, 0.0, 0.0, 0.0, d11, d12, 0.0, d21, d22
    return d00, d01, d02, d10, d11, d12, d20, d21, d22


def _optimal_weights(traces: list[float], form: list[list[float]], present: list[bool],
                     powers: list[float], criterion: Criterion) -> list[float]:
    """One row's optimal CI weights, from its estimates' information traces and determinant form: the
    vertices, then each face's stationary points; the best (the mean of the tied best)."""
    candidates = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    feasible = list(present)
    for face, power in zip(FACES, powers, strict=True):
        _face_candidates(traces, form, present, face, power, criterion, candidates, feasible)
    values = [_objective(weights, traces, form, criterion) if here else INF
              for weights, here in zip(candidates, feasible, strict=True)]
    least = values[0]
    for value in values[1:]:  # numpy's minimum: a NaN wins
        if least == least and (value < least or value != value):
            least = value
    bound = least * TIED
    chosen = [value <= bound for value in values]
    totals = candidates[0] if chosen[0] else [0.0, 0.0, 0.0]
    for weights, here in zip(candidates[1:], chosen[1:], strict=True):
        added = weights if here else (0.0, 0.0, 0.0)  # a 0.0 added still turns a -0.0 total into 0.0
        totals = [totals[0] + added[0], totals[1] + added[1], totals[2] + added[2]]
    ties = sum(chosen)
    if not ties:
        return [_quotient(total, 0.0) for total in totals]
    return [totals[0] / ties, totals[1] / ties, totals[2] / ties]


def _objective(weights: list[float], traces: list[float], form: list[list[float]], criterion: Criterion) -> float:
    """``tr P_c`` or ``det P_c`` at ``weights`` (inf where the fused information is singular)."""
    w0, w1, w2 = weights
    (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = form
    determinant = (w0 * (d00 * w0 + d01 * w1 + d02 * w2) + w1 * (d10 * w0 + d11 * w1 + d12 * w2)
                   + w2 * (d20 * w0 + d21 * w1 + d22 * w2))
    if not determinant > 0.0:
        return INF
    if criterion == "trace":
        return (traces[0] * w0 + traces[1] * w1 + traces[2] * w2) / determinant
    return 1.0 / determinant


def _face_candidates(traces: list[float], form: list[list[float]], present: list[bool], face: tuple[int, ...],
                     power: float, criterion: Criterion, candidates: list[list[float]], feasible: list[bool]) -> None:
    """Append one face's stationary points to ``candidates`` and whether each is feasible to
    ``feasible``: one for "det", one per root (two) for "trace"."""
    ones = [1.0 if j in face else 0.0 for j in range(3)]
    o0, o1, o2 = ones
    t0, t1, t2 = (traces[0] if o0 else 0.0), (traces[1] if o1 else 0.0), (traces[2] if o2 else 0.0)
    f0, f1, f2, f3, f4, f5, f6, f7, f8 = _face_system(form, face)  # solved by the adjugate
    g0, g1, g2 = f4 * f8 - f5 * f7, f2 * f7 - f1 * f8, f1 * f5 - f2 * f4
    g3, g4, g5 = f5 * f6 - f3 * f8, f0 * f8 - f2 * f6, f2 * f3 - f0 * f5
    g6, g7, g8 = f3 * f7 - f4 * f6, f1 * f6 - f0 * f7, f0 * f4 - f1 * f3
    determinant = f0 * g0 + f1 * g3 + f2 * g6
    on_face = all(present[j] for j in face)
    if on_face and abs(determinant) >= DEGENERATE * power:
        usable = True
        a = [g0 * t0 + g1 * t1 + g2 * t2, g3 * t0 + g4 * t1 + g5 * t2, g6 * t0 + g7 * t1 + g8 * t2]
        b = [g0 * o0 + g1 * o1 + g2 * o2, g3 * o0 + g4 * o1 + g5 * o2, g6 * o0 + g7 * o1 + g8 * o2]
        if determinant:
            a = [a[0] / determinant, a[1] / determinant, a[2] / determinant]
            b = [b[0] / determinant, b[1] / determinant, b[2] / determinant]
        else:
            a, b = [_quotient(x, determinant) for x in a], [_quotient(x, determinant) for x in b]
    else:
        usable, a, b = False, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    a_sum, b_sum = a[0] + a[1] + a[2], b[0] + b[1] + b[2]
    if criterion == "det":
        local = [_divide(b[0], b_sum), _divide(b[1], b_sum), _divide(b[2], b_sum)]
        _append(local, usable and b_sum != 0.0, ones, candidates, feasible)
        return
    traced_a = t0 * a[0] + t1 * a[1] + t2 * a[2]
    traced_b = t0 * b[0] + t1 * b[1] + t2 * b[2]
    roots, found = _positive_roots(b_sum, a_sum - traced_b, -traced_a)
    for root, root_found in zip(roots, found, strict=True):
        total = a_sum + root * b_sum
        local = [_divide(a[0] + root * b[0], total), _divide(a[1] + root * b[1], total),
                 _divide(a[2] + root * b[2], total)]
        _append(local, usable and root_found and total != 0.0, ones, candidates, feasible)


def _divide(numerator: float, denominator: float) -> float:
    """``numerator / denominator`` as numpy divides (a zero denominator: see :func:`_quotient`)."""
    return numerator / denominator if denominator else _quotient(numerator, denominator)


def _append(local: list[float], solvable: bool, ones: list[float], candidates: list[list[float]],
            feasible: list[bool]) -> None:
    """A face's candidate: its weights if solvable and on the simplex (else the face's ones, ruled
    out), clipped at 0 and normalised."""
    here = solvable and local[0] >= FEASIBLE and local[1] >= FEASIBLE and local[2] >= FEASIBLE
    # clipped as numpy's maximum(x, 0.0) does: NaN stays, -0.0 becomes 0.0
    w0, w1, w2 = (x if x > 0.0 or x != x else 0.0 for x in (local if here else ones))
    total = w0 + w1 + w2
    if total:
        candidates.append([w0 / total, w1 / total, w2 / total])
    else:
        candidates.append([_quotient(w0, total), _quotient(w1, total), _quotient(w2, total)])
    feasible.append(here)


def _positive_roots(quadratic: float, linear: float, constant: float) -> tuple[tuple[float, float],
                                                                                 tuple[bool, bool]]:
    """``fusion._positive_roots`` of one equation: the two root slots, the smaller first, and which hold one."""
    discriminant = linear * linear - 4.0 * quadratic * constant
    widest = discriminant if discriminant > 0.0 or discriminant != discriminant else 0.0
    q = -0.5 * (linear + math.copysign(math.sqrt(widest), linear))
    linear_only = quadratic == 0.0
    first = _divide(-constant, linear) if linear_only else _divide(q, quadratic)
    real = discriminant >= 0.0
    first_found = (linear != 0.0 if linear_only else real) and first > 0.0
    second = _divide(constant, q)
    second_found = not linear_only and real and q != 0.0 and second > 0.0 and not (first_found and second == first)
    first, second = (first if first_found else INF), (second if second_found else INF)
    smaller, larger = (first, second) if first <= second else (second, first)
    return (smaller, larger), (first_found or second_found, first_found and second_found)


def _fuse(means: list[list[float]], information: list[Entries], weights: list[float]) -> tuple[list[float],
                                                                                           list[list[float]]]:
    """The CI at ``weights`` (``fusion._intersect``): the fused mean and covariance."""
    (x0, y0), (x1, y1), (x2, y2) = means
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = information
    w0, w1, w2 = weights
    fused_xx = w0 * a0 + w1 * a1 + w2 * a2
    fused_xy = w0 * b0 + w1 * b1 + w2 * b2
    fused_yy = w0 * c0 + w1 * c1 + w2 * c2
    summed_x = w0 * (a0 * x0 + b0 * y0) + w1 * (a1 * x1 + b1 * y1) + w2 * (a2 * x2 + b2 * y2)
    summed_y = w0 * (b0 * x0 + c0 * y0) + w1 * (b1 * x1 + c1 * y1) + w2 * (b2 * x2 + c2 * y2)
    xx, xy, yy = _inverse(fused_xx, fused_xy, fused_yy)
    return [xx * summed_x + xy * summed_y, xy * summed_x + yy * summed_y], [[xx, xy], [xy, yy]]
