"""One robot's scalars and a team's arrays give the same bits (world/elementwise.py and the scalar
paths of world/geometry.py, world/ring.py, agents/laws.py and agents/controller.py)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.agents.controller import MidpointController
from ringtrack.agents.laws import angular_step, fresh_step, guarded_step, trigger_reasons
from ringtrack.world.elementwise import anywhere, choose, clip, everywhere, reduce_last, scalar
from ringtrack.world.geometry import ConvexRegion, angle_of
from ringtrack.world.params import ControlParams
from ringtrack.world.ring import local_frame, midpoint, wrap
from ringtrack.world.scenario import load_scenario

SCENARIO = load_scenario("paper-stationary")
REGION: ConvexRegion = SCENARIO.region
angles = st.floats(-20.0, 20.0, allow_nan=False)
coarse = st.integers(-64, 64).map(lambda eighths: np.deg2rad(eighths / 8.0))  # ties at coarse settings
ages = st.integers(0, 40)


def bits(value: object) -> bytes:
    return np.asarray(value, dtype=float).tobytes()


def same(one: object, team: np.ndarray, index: int) -> bool:
    return bits(one) == bits(np.asarray(team)[index])


def params(law: str = "prop", omega_deg: float = 1.0, dt: float = 0.1, sigma_deg: float = 0.1) -> ControlParams:
    return ControlParams(law=law, omega_max=np.deg2rad(omega_deg), dt=dt, sigma=np.deg2rad(sigma_deg))


@given(st.lists(st.integers(1, 9), min_size=1, max_size=4), st.sampled_from(["minimum", "maximum", "and", "or"]),
       st.integers(0, 2**32 - 1))
def test_reduce_last_is_numpys_reduction_along_the_last_axis(shape: list[int], name: str, seed: int) -> None:
    """Small and large arrays (either side of SHORT_REDUCTION), NaN and signed zeros included: the
    same values and the same shape as ``ufunc.reduce(values, axis=-1)`` (a tie of 0.0 and -0.0 may
    keep either sign, as numpy's own loops do)."""
    rng = np.random.default_rng(seed)
    values = rng.choice([-1.5, -0.0, 0.0, 2.0, np.nan, -np.inf], size=shape) * rng.random(shape)
    if name in ("and", "or"):
        values = values > 0
    ufunc = {"minimum": np.minimum, "maximum": np.maximum, "and": np.logical_and, "or": np.logical_or}[name]
    expected, reduced = ufunc.reduce(values, axis=-1), reduce_last(ufunc, values)
    assert reduced.shape == expected.shape and reduced.dtype == expected.dtype
    np.testing.assert_array_equal(reduced, expected)  # NaN where NaN, -0.0 equal to 0.0


@given(st.lists(st.integers(0, 5), max_size=3), st.integers(0, 2**32 - 1), st.booleans())
def test_anywhere_and_everywhere_are_any_and_all(shape: list[int], seed: int, floats: bool) -> None:
    rng = np.random.default_rng(seed)
    values = rng.choice([0.0, -0.0, 1.5, np.nan], size=shape) if floats else rng.random(shape) < 0.7
    assert anywhere(values) is bool(values.any()) and everywhere(values) is bool(values.all())
    assert anywhere(np.True_) and not anywhere(False) and everywhere(True) and not everywhere(np.False_)


def test_helpers_choose_and_clip_like_numpy() -> None:
    assert choose(np.True_, 1.0, 2.0) == 1.0 and choose(False, 1.0, 2.0) == 2.0
    np.testing.assert_array_equal(choose(np.array([True, False]), 1.0, 2.0), [1.0, 2.0])
    assert clip(3.0, 0.0, 1.0) == 1.0 and clip(-0.5, 0.0) == 0.0 and clip(0.25, 0.0, 1.0) == 0.25
    np.testing.assert_array_equal(clip(np.array([-1.0, 0.5, 2.0]), 0.0, 1.0), [0.0, 0.5, 1.0])
    assert type(scalar(np.zeros((), dtype=np.int64))) is np.int64
    team = np.zeros(3)
    assert scalar(team) is team


@given(st.lists(st.tuples(angles, angles, angles), min_size=1, max_size=8))
def test_ring_arithmetic_of_one_robot_equals_the_team(rows: list[tuple[float, float, float]]) -> None:
    team = np.array(rows)
    team_minus, team_plus = local_frame(team[:, 0], team[:, 1], team[:, 2])
    for index, (theta, before, after) in enumerate(rows):
        assert same(wrap(theta), wrap(team[:, 0]), index)
        m_minus, m_plus = local_frame(theta, before, after)
        assert same(m_minus, team_minus, index) and same(m_plus, team_plus, index)
        assert same(midpoint(m_minus, theta, m_plus), midpoint(team_minus, team[:, 0], team_plus), index)


@settings(max_examples=200)
@given(st.lists(st.tuples(coarse, coarse, coarse, ages, ages, st.booleans()), min_size=1, max_size=8),
       st.sampled_from(["prop", "deadbeat"]), st.sampled_from([0.1, 0.5]))
def test_laws_of_one_robot_equal_the_team(rows: list, law: str, dt: float) -> None:
    control = params(law, dt=dt)
    theta, before, after = (np.array([row[k] for row in rows]) for k in range(3))
    c_minus, c_plus = (np.array([row[k] for row in rows], dtype=np.int64) for k in (3, 4))
    fresh = np.array([row[5] for row in rows])
    m_minus, m_plus = theta - np.abs(before) - 1e-3, theta + np.abs(after) + 1e-3
    team_reasons = trigger_reasons(theta, m_minus, m_plus, c_minus, c_plus, control)
    team_step = angular_step(theta, m_minus, m_plus, c_minus, c_plus, fresh, control)
    for index in range(len(rows)):
        one = (float(theta[index]), float(m_minus[index]), float(m_plus[index]))
        ages_of_one = (c_minus[index], c_plus[index])  # numpy scalars, as a robot's controller holds them
        assert int(trigger_reasons(*one, *ages_of_one, control)) == int(np.asarray(team_reasons)[index])
        assert same(angular_step(*one, *ages_of_one, fresh[index], control), team_step, index)
        offset = float(m_plus[index] - theta[index])
        assert same(fresh_step(offset, control), fresh_step(m_plus - theta, control), index)
        assert same(guarded_step(offset, 0.01, control.max_step), guarded_step(m_plus - theta, 0.01, control.max_step),
                    index)


inside = st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0))


def interior_point(weights: tuple[float, float]) -> np.ndarray:
    """A point between the Chebyshev centre and (most of the way to) a vertex."""
    centre, _ = REGION.chebyshev_centre
    vertex = REGION.vertices[int(weights[0] * (len(REGION.vertices) - 1))]
    return centre + 0.9 * weights[1] * (vertex - centre)


@given(st.lists(st.tuples(angles, inside), min_size=1, max_size=8))
def test_geometry_of_one_robot_equals_the_team(rows: list[tuple[float, tuple[float, float]]]) -> None:
    thetas = np.array([theta for theta, _ in rows])
    centres = np.array([interior_point(weights) for _, weights in rows])
    team_points = REGION.boundary_point(thetas, centres)
    team_angles = angle_of(team_points, centres)
    for index, (theta, _) in enumerate(rows):
        point = REGION.boundary_point(theta, centres[index])
        assert bits(point) == bits(team_points[index])
        assert same(angle_of(point, centres[index]), team_angles, index)


@settings(max_examples=50)
@given(st.lists(st.tuples(inside, inside, inside, st.booleans(), st.booleans()), min_size=4, max_size=30),
       st.sampled_from(["prop", "deadbeat"]))
def test_a_robot_controller_equals_a_team_controller(steps: list, law: str) -> None:
    """Feed one robot's controller (scalars) and a team of three (arrays, the robot in the middle)
    the same steps; its memory, trigger and goal keep the same bits."""
    control = params(law, omega_deg=5.0)
    centre = REGION.chebyshev_centre[0]

    def on_boundary(weights: tuple[float, float]) -> np.ndarray:
        return REGION.boundary_point(6.283 * weights[0], centre)

    start = on_boundary(steps[0][0])
    one = MidpointController(REGION, control, start)
    team = MidpointController(REGION, control, np.stack([start, start, start]))
    for step, (own, before, after, fresh_before, fresh_after) in enumerate(steps, start=1):
        position = on_boundary(own)
        reasons = one.observe(step, position, centre)
        team_reasons = team.observe(step, np.stack([position] * 3), centre)
        assert int(reasons) == int(team_reasons[1])
        fresh = (fresh_before or step == 1, fresh_after or step == 1)
        one.receive(on_boundary(before), on_boundary(after), np.bool_(fresh[0]), np.bool_(fresh[1]),
                    np.int64(0), np.int64(0))
        team.receive(np.stack([on_boundary(before)] * 3), np.stack([on_boundary(after)] * 3),
                     np.full(3, fresh[0]), np.full(3, fresh[1]), np.zeros(3, dtype=np.int64),
                     np.zeros(3, dtype=np.int64))
        for name in ("theta", "m_minus", "m_plus", "guaranteed_offset", "predecessor_age", "successor_age"):
            assert same(getattr(one, name), getattr(team, name), 1), name
        assert bits(one.goal()) == bits(team.goal()[1])


def test_a_team_controller_keeps_its_arrays_when_told_by_scalars() -> None:
    """Which path a controller takes depends on its own shape, not on its arguments': a team given
    the default ``fresh=True`` and age 0 keeps one age and one flag per robot."""
    centre = REGION.chebyshev_centre[0]
    positions = REGION.boundary_point(np.array([0.5, 2.5, 4.5]), centre)
    team = MidpointController(REGION, params(), positions)
    team.observe(1, positions, centre)
    team.receive(np.roll(positions, 1, axis=0), np.roll(positions, -1, axis=0))
    assert team.predecessor_age.shape == team.successor_age.shape == (3,)
    assert team.predecessor_known.shape == (3,) and bool(np.all(team.successor_known))
    assert team.goal().shape == (3, 2)
