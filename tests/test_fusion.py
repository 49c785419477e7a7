"""agents/fusion.py against docs/algorithms.md section 8 and oracle 16 (covariance intersection).

Every reference quantity here is computed independently from the formulas of docs/algorithms.md
``P_c = (sum_k w_k P_k^{-1})^{-1}``, ``x_c = P_c sum_k w_k P_k^{-1} x_k``, with plain matrix inverses
and a numeric search over the weights (scipy), not from the closed form under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from scipy.optimize import minimize, minimize_scalar

from ringtrack.agents.fusion import covariance_intersection, intersect, intersect_at, sequential_intersection
from ringtrack.agents.fusion_rows import intersect_rows

CRITERIA = ["trace", "det"]


# ---------------------------------------------------------------------------- strategies
def rotation(angle: float) -> np.ndarray:
    return np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


@st.composite
def spd(draw: st.DrawFn, max_log_condition: float = 6.0) -> np.ndarray:
    """A random symmetric positive definite 2x2 matrix: eigenvalues ``s`` and ``s * 10**c`` with
    ``s`` log-uniform in [1e-3, 1e3] and condition number up to ``10**max_log_condition``, at a random tilt."""
    scale = 10.0 ** draw(st.floats(-3.0, 3.0))
    condition = 10.0 ** draw(st.one_of(st.floats(0.0, max_log_condition), st.just(max_log_condition)))
    tilt = draw(st.floats(0.0, math.pi))
    turn = rotation(tilt)
    matrix = turn @ np.diag([scale, scale * condition]) @ turn.T
    return 0.5 * (matrix + matrix.T)


def means() -> st.SearchStrategy[np.ndarray]:
    coordinate = st.floats(-100.0, 100.0, allow_subnormal=False)
    return st.tuples(coordinate, coordinate).map(lambda point: np.array(point, dtype=float))


@st.composite
def contraction(draw: st.DrawFn) -> np.ndarray:
    """A 2x2 matrix K with spectral norm <= 1 (norm exactly 1 often: the worst-case correlations)."""
    unit = st.one_of(st.just(1.0), st.floats(0.0, 1.0))
    singular = np.diag([draw(unit), draw(unit)])
    left = rotation(draw(st.floats(0.0, 2.0 * math.pi))) @ np.diag([1.0, draw(st.sampled_from([1.0, -1.0]))])
    right = rotation(draw(st.floats(0.0, 2.0 * math.pi)))
    return left @ singular @ right.T


# ---------------------------------------------------------------------------- independent helpers
def sqrtm(matrix: np.ndarray) -> np.ndarray:
    values, vectors = np.linalg.eigh(matrix)
    return vectors @ np.diag(np.sqrt(values)) @ vectors.T


def min_eigenvalue(matrix: np.ndarray) -> float:
    return float(np.linalg.eigvalsh(0.5 * (matrix + matrix.T)).min())


def fused_covariance(weights, covariances) -> np.ndarray:
    information = sum(w * np.linalg.inv(P) for w, P in zip(weights, covariances, strict=True))
    return np.linalg.inv(information)


def fused_mean(weights, means_, covariances) -> np.ndarray:
    combined = fused_covariance(weights, covariances)
    return combined @ sum(w * np.linalg.solve(P, x) for w, x, P in zip(weights, means_, covariances, strict=True))


def objective(weights, covariances, criterion: str) -> float:
    return objective_from_information(weights, np.array([np.linalg.inv(P) for P in covariances]), criterion)


def objective_from_information(weights, informations: np.ndarray, criterion: str) -> float:
    """tr or det of P_c = M^{-1}, M = sum w_k I_k, by the 2x2 identities tr M^{-1} = tr M / det M and
    det M^{-1} = 1 / det M (cheap enough for the numeric searches)."""
    m00 = m01 = m11 = 0.0
    for w, information in zip(weights, informations, strict=True):
        m00 += w * information[0, 0]
        m01 += w * information[0, 1]
        m11 += w * information[1, 1]
    determinant = m00 * m11 - m01 * m01
    if not determinant > 0.0:
        return math.inf
    return (m00 + m11) / determinant if criterion == "trace" else 1.0 / determinant


def numeric_optimum_two(a: np.ndarray, b: np.ndarray, criterion: str) -> float:
    """min over lambda in [0, 1] of the criterion: bounded Brent plus both endpoints."""

    informations = np.array([np.linalg.inv(a), np.linalg.inv(b)])

    def value(lam: float) -> float:
        return objective_from_information((lam, 1.0 - lam), informations, criterion)

    found = minimize_scalar(value, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-12})
    return min(float(found.fun), value(0.0), value(1.0))


def softmax(logits: np.ndarray) -> np.ndarray:
    shifted = np.exp(logits - logits.max())
    return shifted / shifted.sum()


def numeric_optimum_simplex(covariances, criterion: str) -> float:
    """min of the criterion over the simplex of weights: Nelder-Mead over softmax logits from several
    starts, plus the vertices and the optimum of every pair (the edges)."""
    count = len(covariances)
    informations = np.array([np.linalg.inv(P) for P in covariances])

    def value(free: np.ndarray) -> float:
        return objective_from_information(softmax(np.concatenate([free, [0.0]])), informations, criterion)

    best = min(objective(np.eye(count)[k], covariances, criterion) for k in range(count))
    for j in range(count):
        for k in range(j + 1, count):
            best = min(best, numeric_optimum_two_in(covariances, j, k, criterion))
    starts = [np.zeros(count - 1)] + [3.0 * row for row in np.vstack([np.eye(count - 1), -np.ones((1, count - 1))])]
    starts += [np.array(start, dtype=float) for start in ([1.0, -1.0], [-2.0, 2.0], [0.5, 2.5])[: 3 if count == 3 else 0]]
    for start in starts:
        found = minimize(value, start, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-14, "maxiter": 600})
        best = min(best, float(found.fun))
    return best


def numeric_optimum_two_in(covariances, j: int, k: int, criterion: str) -> float:
    informations = np.array([np.linalg.inv(covariances[j]), np.linalg.inv(covariances[k])])

    def value(lam: float) -> float:
        return objective_from_information((lam, 1.0 - lam), informations, criterion)

    found = minimize_scalar(value, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-12})
    return float(found.fun)


def assert_on_simplex(weights: np.ndarray, count: int) -> None:
    assert weights.shape == (count,)
    assert np.all(weights >= 0.0)
    assert abs(weights.sum() - 1.0) <= 1e-12


# ---------------------------------------------------------------------------- identical inputs
@pytest.mark.parametrize("criterion", CRITERIA)
@pytest.mark.parametrize("count", [1, 2, 3])
@given(mean=means(), covariance=spd())
def test_identical_inputs_are_returned(criterion, count, mean, covariance):
    fused = covariance_intersection([mean] * count, [covariance] * count, criterion)
    np.testing.assert_allclose(fused.mean, mean, rtol=1e-8, atol=1e-8 * max(np.abs(mean).max(), 1.0))
    np.testing.assert_allclose(fused.covariance, covariance, rtol=0, atol=1e-8 * np.abs(covariance).max())
    assert_on_simplex(fused.weights, count)


# ---------------------------------------------------------------------------- the CI formulas with the returned weights
@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), xc=means(), a=spd(), b=spd(), c=spd(), three=st.booleans())
def test_result_is_the_ci_formula_at_its_weights(criterion, xa, xb, xc, a, b, c, three):
    means_ = [xa, xb, xc] if three else [xa, xb]
    covariances = [a, b, c] if three else [a, b]
    fused = covariance_intersection(means_, covariances, criterion)
    assert_on_simplex(fused.weights, len(means_))
    expected = fused_covariance(fused.weights, covariances)
    np.testing.assert_allclose(fused.covariance, expected, rtol=0, atol=1e-9 * np.trace(expected))
    np.testing.assert_array_equal(fused.covariance, fused.covariance.T)  # symmetrised
    # x_c = P_c sum w_k P_k^{-1} x_k, compared in the Mahalanobis metric of P_c
    difference = fused.mean - fused_mean(fused.weights, means_, covariances)
    spread = max(np.abs(x).max() for x in means_) + 1.0
    assert np.linalg.norm(difference) <= 1e-8 * spread


# ---------------------------------------------------------------------------- never worse than the inputs, never below the product
@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), a=spd(), b=spd())
def test_fused_size_at_most_the_smaller_input(criterion, xa, xb, a, b):
    fused = covariance_intersection([xa, xb], [a, b], criterion)
    if criterion == "trace":
        scale = max(np.trace(a), np.trace(b))
        assert np.trace(fused.covariance) <= min(np.trace(a), np.trace(b)) + 1e-10 * scale
    else:
        # A determinant's relative rounding error grows with the condition number (about eps * cond).
        conditioning = max(np.linalg.cond(a), np.linalg.cond(b))
        scale = max(np.linalg.det(a), np.linalg.det(b)) * max(1e-10, 8 * np.finfo(float).eps * conditioning)
        assert np.linalg.det(fused.covariance) <= min(np.linalg.det(a), np.linalg.det(b)) + scale


@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), a=spd(), b=spd())
def test_fused_covariance_dominates_the_independent_product(criterion, xa, xb, a, b):
    fused = covariance_intersection([xa, xb], [a, b], criterion)
    product = np.linalg.inv(np.linalg.inv(a) + np.linalg.inv(b))
    assert min_eigenvalue(fused.covariance - product) >= -1e-9 * np.trace(fused.covariance)


# ---------------------------------------------------------------------------- consistency for any correlation
def assert_consistent(fused, a: np.ndarray, b: np.ndarray, k: np.ndarray) -> None:
    """Sigma_c - G S G^T >= -1e-9 tr Sigma_c with G = Sigma_c [lam Sigma_a^-1, (1-lam) Sigma_b^-1], lam the
    weight of ``fused``, S the joint covariance with cross term C = Sigma_a^{1/2} K Sigma_b^{1/2 T}, ||K|| <= 1."""
    lam = fused.weights[0]
    cross = sqrtm(a) @ k @ sqrtm(b).T
    joint = np.block([[a, cross], [cross.T, b]])
    gain = fused.covariance @ np.hstack([lam * np.linalg.inv(a), (1.0 - lam) * np.linalg.inv(b)])
    error_covariance = gain @ joint @ gain.T
    assert min_eigenvalue(fused.covariance - error_covariance) >= -1e-9 * np.trace(fused.covariance)


@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), a=spd(), b=spd(), k=contraction())
def test_consistent_for_any_cross_covariance(criterion, xa, xb, a, b, k):
    """At the weight CI chooses."""
    assert_consistent(covariance_intersection([xa, xb], [a, b], criterion), a, b, k)


@given(xa=means(), xb=means(), a=spd(), b=spd(), k=contraction(),
       lam=st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0)))
def test_consistent_for_any_cross_covariance_and_any_weight(xa, xb, a, b, k, lam):
    """Oracle 16 holds for every lambda in [0, 1], not only the optimal one; the CI at a given lambda
    is the formula of docs/algorithms.md section 8."""
    fused = intersect_at([xa, xb], [a, b], [lam, 1.0 - lam])
    np.testing.assert_array_equal(fused.weights, [lam, 1.0 - lam])
    expected = fused_covariance(fused.weights, [a, b])
    np.testing.assert_allclose(fused.covariance, expected, rtol=0, atol=1e-9 * np.trace(expected))
    spread = max(np.abs(xa).max(), np.abs(xb).max()) + 1.0
    assert np.linalg.norm(fused.mean - fused_mean(fused.weights, [xa, xb], [a, b])) <= 1e-8 * spread
    assert_consistent(fused, a, b, k)


@pytest.mark.parametrize("criterion", CRITERIA)
@given(
    estimates=st.lists(st.tuples(means(), spd(max_log_condition=4.0)), min_size=3, max_size=3),
    raw=st.lists(st.floats(-1.0, 1.0), min_size=24, max_size=24),
)
def test_three_way_consistent_for_any_joint_covariance(criterion, estimates, raw):
    """The joint covariance S = L L^T with block rows L_k = Sigma_k^{1/2} U_k, U_k (2 x 4) with
    orthonormal rows, has the given diagonal blocks Sigma_k and arbitrary admissible correlations."""
    means_ = [mean for mean, _ in estimates]
    covariances = [covariance for _, covariance in estimates]
    fused = covariance_intersection(means_, covariances, criterion)
    rows = []
    for index, covariance in enumerate(covariances):
        columns = np.array(raw[8 * index : 8 * index + 8]).reshape(4, 2)
        assume(np.linalg.svd(columns, compute_uv=False).min() > 1e-3)
        basis, _ = np.linalg.qr(columns)  # (4, 2), orthonormal columns
        rows.append(sqrtm(covariance) @ basis.T)
    factor = np.vstack(rows)
    joint = factor @ factor.T
    for index, covariance in enumerate(covariances):  # the construction keeps the marginals
        np.testing.assert_allclose(joint[2 * index : 2 * index + 2, 2 * index : 2 * index + 2], covariance, rtol=0, atol=1e-9 * np.trace(covariance))
    gain = fused.covariance @ np.hstack([w * np.linalg.inv(P) for w, P in zip(fused.weights, covariances, strict=True)])
    assert min_eigenvalue(fused.covariance - gain @ joint @ gain.T) >= -1e-9 * np.trace(fused.covariance)


# ---------------------------------------------------------------------------- symmetry
@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), a=spd(), b=spd())
def test_symmetric_in_its_inputs(criterion, xa, xb, a, b):
    # Equal covariances (also up to rounding) tie every lambda, so the choice of the fused mean is
    # arbitrary unless broken symmetrically: that case is test_symmetric_when_the_covariances_tie.
    assume(not np.allclose(a, b, rtol=1e-6, atol=1e-6 * np.abs(a).max()))
    forward = covariance_intersection([xa, xb], [a, b], criterion)
    backward = covariance_intersection([xb, xa], [b, a], criterion)
    # Rounding grows with the inputs' condition number (up to 1e6 here) and with the fused mean, which
    # nearly singular covariances can put far outside the inputs' hull.
    spread = max(np.abs(xa).max(), np.abs(xb).max(), np.abs(forward.mean).max()) + 1.0
    condition = max(np.linalg.cond(a), np.linalg.cond(b))
    assert np.linalg.norm(forward.mean - backward.mean) <= 1e-10 * spread + 8 * np.finfo(float).eps * condition * spread
    np.testing.assert_allclose(forward.covariance, backward.covariance, rtol=0, atol=1e-10 * np.abs(forward.covariance).max())
    np.testing.assert_allclose(forward.weights, backward.weights[::-1], rtol=0, atol=1e-10)


@pytest.mark.parametrize("criterion", CRITERIA)
def test_symmetric_when_the_covariances_tie(criterion):
    """Equal covariances make every lambda optimal (tr and det of P_c are constant); the oracle
    CI(a, b) = CI(b, a) still asks for the same fused estimate whichever input comes first."""
    covariance = np.array([[2.0, 0.3], [0.3, 1.0]])
    xa, xb = np.array([0.0, 0.0]), np.array([1.0, 2.0])
    forward = covariance_intersection([xa, xb], [covariance, covariance], criterion)
    backward = covariance_intersection([xb, xa], [covariance, covariance], criterion)
    np.testing.assert_allclose(forward.covariance, covariance, rtol=1e-12)
    np.testing.assert_allclose(forward.mean, backward.mean, rtol=0, atol=1e-10)


# ---------------------------------------------------------------------------- optimality of the closed form
@pytest.mark.parametrize("criterion", CRITERIA)
@given(xa=means(), xb=means(), a=spd(), b=spd())
def test_two_way_closed_form_is_the_optimum(criterion, xa, xb, a, b):
    fused = covariance_intersection([xa, xb], [a, b], criterion)
    achieved = objective(fused.weights, [a, b], criterion)
    assert achieved <= numeric_optimum_two(a, b, criterion) * (1.0 + 1e-9)
    # ... and the returned covariance is the one the weights give
    size = np.trace(fused.covariance) if criterion == "trace" else np.linalg.det(fused.covariance)
    assert size == pytest.approx(achieved, rel=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("criterion", CRITERIA)
@given(estimates=st.lists(st.tuples(means(), spd(max_log_condition=4.0)), min_size=3, max_size=3))
def test_three_way_closed_form_is_the_optimum(criterion, estimates):
    means_ = [mean for mean, _ in estimates]
    covariances = [covariance for _, covariance in estimates]
    fused = covariance_intersection(means_, covariances, criterion)
    assert_on_simplex(fused.weights, 3)
    achieved = objective(fused.weights, covariances, criterion)
    assert achieved <= numeric_optimum_simplex(covariances, criterion) * (1.0 + 1e-9)


@st.composite
def comparable_triples(draw: st.DrawFn) -> list[np.ndarray]:
    """Three covariances of about the same size and shape at different tilts, where the joint
    optimum is often interior (all three weights positive)."""
    scale = 10.0 ** draw(st.floats(-2.0, 2.0))
    condition = 10.0 ** draw(st.floats(0.2, 3.0))
    triple = []
    for _ in range(3):
        turn = rotation(draw(st.floats(0.0, math.pi)))
        wobble = 10.0 ** draw(st.floats(-0.15, 0.15))
        matrix = turn @ np.diag([scale * wobble, scale * wobble * condition]) @ turn.T
        triple.append(0.5 * (matrix + matrix.T))
    return triple


@pytest.mark.slow
@pytest.mark.parametrize("criterion", CRITERIA)
@given(covariances=comparable_triples())
def test_three_way_closed_form_is_the_optimum_for_comparable_estimates(criterion, covariances):
    fused = covariance_intersection([np.zeros(2)] * 3, covariances, criterion)
    assert_on_simplex(fused.weights, 3)
    achieved = objective(fused.weights, covariances, criterion)
    assert achieved <= numeric_optimum_simplex(covariances, criterion) * (1.0 + 1e-9)


@pytest.mark.parametrize("criterion", CRITERIA)
def test_three_way_interior_optimum_by_symmetry(criterion):
    """Three copies of diag(1, 10) tilted by 0, 60 and 120 degrees: by symmetry the weights are 1/3 each
    and the fused information is the isotropic average (1 + 1/10)/2 I, so P_c = (2/1.1) I."""
    shape = np.diag([1.0, 10.0])
    covariances = [rotation(k * math.pi / 3) @ shape @ rotation(k * math.pi / 3).T for k in range(3)]
    means_ = [np.array([1.0, 0.0]), np.array([0.0, 2.0]), np.array([-1.0, -1.0])]
    fused = covariance_intersection(means_, covariances, criterion)
    np.testing.assert_allclose(fused.weights, [1 / 3, 1 / 3, 1 / 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fused.covariance, (2.0 / 1.1) * np.eye(2), rtol=0, atol=1e-9)
    expected_mean = (2.0 / 1.1) * sum(np.linalg.solve(P, x) for P, x in zip(covariances, means_, strict=True)) / 3
    np.testing.assert_allclose(fused.mean, expected_mean, rtol=0, atol=1e-9)
    # strictly better than fusing any two of them (the optimum is interior, not on an edge)
    size = np.trace if criterion == "trace" else np.linalg.det
    for pair in ([0, 1], [0, 2], [1, 2]):
        best_pair = covariance_intersection([means_[k] for k in pair], [covariances[k] for k in pair], criterion)
        assert size(fused.covariance) < size(best_pair.covariance) * (1 - 1e-3)


@pytest.mark.parametrize("criterion", CRITERIA)
@given(estimates=st.lists(st.tuples(means(), spd()), min_size=3, max_size=3))
def test_three_way_never_worse_than_sequential(criterion, estimates):
    means_ = [mean for mean, _ in estimates]
    covariances = [covariance for _, covariance in estimates]
    joint = covariance_intersection(means_, covariances, criterion)
    pairwise = sequential_intersection(means_, covariances, criterion)
    size = np.trace if criterion == "trace" else np.linalg.det
    assert size(joint.covariance) <= size(pairwise.covariance) * (1.0 + 1e-9)
    # the sequential result is itself a CI of the two-stage inputs: check its first stage
    first = covariance_intersection(means_[:2], covariances[:2], criterion)
    second = covariance_intersection([first.mean, means_[2]], [first.covariance, covariances[2]], criterion)
    np.testing.assert_array_equal(pairwise.mean, second.mean)
    np.testing.assert_array_equal(pairwise.covariance, second.covariance)


def test_two_way_closed_form_matches_brent_on_a_hand_example():
    """A 2-D example with an interior optimum: the weight agrees with bounded Brent to 1e-6."""
    a = np.diag([1.0, 10.0])
    b = np.diag([10.0, 1.0])
    for criterion in CRITERIA:
        fused = covariance_intersection([np.zeros(2), np.ones(2)], [a, b], criterion)
        assert fused.weights[0] == pytest.approx(0.5, abs=1e-9)  # symmetric problem: lambda = 1/2
        np.testing.assert_allclose(fused.covariance, np.linalg.inv(0.5 * np.linalg.inv(a) + 0.5 * np.linalg.inv(b)), rtol=1e-12)
        # x_c = P_c (0.5 a^-1 0 + 0.5 b^-1 1)
        np.testing.assert_allclose(fused.mean, fused.covariance @ (0.5 * np.linalg.inv(b) @ np.ones(2)), rtol=1e-12)


# ---------------------------------------------------------------------------- scalar case, per axis
variances = st.floats(-3.0, 3.0).map(lambda e: 10.0**e)


@given(
    xa=means(),
    xb=means(),
    sa=st.tuples(variances, variances),
    sb=st.tuples(variances, variances),
    isotropic=st.booleans(),
    lam=st.one_of(st.none(), st.floats(0.0, 1.0)),
    criterion=st.sampled_from(CRITERIA),
)
def test_axis_aligned_covariances_fuse_coordinatewise_on_the_segment(xa, xb, sa, sb, isotropic, lam, criterion):
    """Oracle 16's scalar case. Diagonal covariances decouple CI into one scalar CI per axis:
    x_c[i] = w_i x_a[i] + (1 - w_i) x_b[i] with w_i = (lam / a_i) / (lam / a_i + (1 - lam) / b_i) in [0, 1],
    at CI's own lambda (None; interior whenever the variances cross between the axes) and at any
    lambda. Isotropic covariances give one w for both axes: x_c on the segment from x_a to x_b."""
    if isotropic:
        sa, sb = (sa[0], sa[0]), (sb[0], sb[0])
    a, b = np.diag(sa), np.diag(sb)
    fused = covariance_intersection([xa, xb], [a, b], criterion) if lam is None else intersect_at([xa, xb], [a, b], [lam, 1 - lam])
    weight = fused.weights[0]
    information = weight / np.array(sa) + (1.0 - weight) / np.array(sb)
    share = (weight / np.array(sa)) / information
    assert np.all((share >= 0.0) & (share <= 1.0))
    spread = max(np.abs(xa).max(), np.abs(xb).max()) + 1.0
    np.testing.assert_allclose(fused.mean, share * xa + (1.0 - share) * xb, rtol=0, atol=1e-9 * spread)
    np.testing.assert_allclose(fused.covariance, np.diag(1.0 / information), rtol=1e-9, atol=0)
    if isotropic:
        span, offset = xb - xa, fused.mean - xa
        assert abs(offset[0] * span[1] - offset[1] * span[0]) <= 1e-9 * spread * (np.linalg.norm(span) + 1.0)
        if lam is None:  # P_c = s I with 1/s linear in lambda: the optimum is the smaller input
            assert np.trace(fused.covariance) == pytest.approx(2.0 * min(sa[0], sb[0]), rel=1e-9)


def test_axis_aligned_optimum_is_strictly_inside_the_box():
    """diag(1, 10) and diag(10, 1): lambda = 1/2 by symmetry, and each coordinate of x_c is a proper
    convex combination (weights 10/11 and 1/11), neither input nor the midpoint."""
    xa, xb = np.array([0.0, 0.0]), np.array([11.0, 22.0])
    fused = covariance_intersection([xa, xb], [np.diag([1.0, 10.0]), np.diag([10.0, 1.0])])
    np.testing.assert_allclose(fused.weights, [0.5, 0.5], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fused.mean, [1.0, 20.0], rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- batches
@pytest.mark.parametrize("criterion", CRITERIA)
@given(rows=st.lists(st.tuples(st.lists(means(), min_size=3, max_size=3), st.lists(spd(), min_size=3, max_size=3),
                               st.lists(st.booleans(), min_size=2, max_size=2)), min_size=1, max_size=6))
def test_a_row_of_a_batch_fuses_as_it_would_alone(rows, criterion):
    """:func:`intersect` over a batch with absent slots: each row bit for bit what the same row gives
    in a batch of one (the robot process fuses a batch of one; the engine every robot of every trial
    at once), and to rounding what :func:`covariance_intersection` gives for its present estimates."""
    batch_means = np.array([row_means for row_means, _, _ in rows])
    batch_covariances = np.array([covariances for _, covariances, _ in rows])
    present = np.array([[True, *told] for _, _, told in rows])
    fused = intersect(batch_means, batch_covariances, present, criterion)
    for index in range(len(rows)):
        alone = intersect(batch_means[index : index + 1], batch_covariances[index : index + 1],
                          present[index : index + 1], criterion)
        np.testing.assert_array_equal(fused.mean[index], alone.mean[0])
        np.testing.assert_array_equal(fused.covariance[index], alone.covariance[0])
        there = present[index]
        only = covariance_intersection(batch_means[index, there], batch_covariances[index, there], criterion)
        scale = np.abs(batch_means[index, there]).max() + np.sqrt(np.trace(only.covariance))
        np.testing.assert_allclose(fused.mean[index], only.mean, rtol=1e-9, atol=1e-9 * scale)
        np.testing.assert_allclose(fused.covariance[index], only.covariance, rtol=1e-9,
                                   atol=1e-12 * np.trace(only.covariance))
        np.testing.assert_allclose(fused.weights[index, there], only.weights, atol=1e-9)
        assert np.all(fused.weights[index, ~there] == 0.0)


@st.composite
def rows_of_three(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A batch of 1-6 rows of three estimates, the first present, the two told ones present or not;
    some rows with equal covariances (every weight optimal: the tie rule decides) or equal means."""
    rows = draw(st.integers(1, 6))
    batch_means, batch_covariances = [], []
    for _ in range(rows):
        tie = draw(st.sampled_from(["none", "covariances", "both"]))
        covariance = draw(spd())
        batch_covariances.append([covariance] * 3 if tie != "none" else [covariance, draw(spd()), draw(spd())])
        mean = draw(means())
        batch_means.append([mean] * 3 if tie == "both" else [mean, draw(means()), draw(means())])
    told = draw(st.lists(st.lists(st.booleans(), min_size=2, max_size=2), min_size=rows, max_size=rows))
    return np.array(batch_means), np.array(batch_covariances), np.array([[True, *pair] for pair in told])


@pytest.mark.parametrize("criterion", CRITERIA)
@given(batch=rows_of_three())
def test_rows_fused_in_floats_are_the_batched_bits(criterion, batch):
    """:func:`intersect_rows` (Python floats, for the few rows a robot or a small team fuses) gives
    byte for byte what the batched :func:`intersect` gives: a robot process and the engine agree
    whichever of the two fuses their rows."""
    batch_means, batch_covariances, present = batch
    batched = intersect(batch_means, batch_covariances, present, criterion)
    in_floats = intersect_rows(batch_means, batch_covariances, present, criterion)
    for name in ("mean", "covariance", "weights"):
        expected, got = getattr(batched, name), getattr(in_floats, name)
        assert got.dtype == expected.dtype and got.shape == expected.shape
        assert got.tobytes() == expected.tobytes(), name
