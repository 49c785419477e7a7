"""Trigger ties are decided as in exact arithmetic.

At dt = 0.5 s, omega_max = 1 deg/s and sigma = 0.1 deg, starting from whole degrees, every quantity
of the self-triggered rule is a multiple of 1/8 degree: exact in degrees, where the paper's authors
computed, but not in radians, where the code computes. Equality in T1 (``ubd >= max(|gV - theta|,
sigma)``) then happens often, and rounding would decide it either way. The reference below runs the
rule in exact rational degrees on the circle about the target; the engine must poll at exactly the
same steps for the same reasons.
"""

from __future__ import annotations

from fractions import Fraction

import msgspec
import numpy as np

from ringtrack.agents import engine
from ringtrack.agents.laws import Trigger
from ringtrack.world.scenario import Scenario, load_scenario, resolve

DT = Fraction(1, 2)  # s
OMEGA = Fraction(1)  # deg/s
SIGMA = Fraction(1, 10)  # deg
STARTS = [(10, 20, 35, 100, 200, 300), (0, 7, 90, 91, 180, 270), (5, 50, 95, 140, 185, 330)]
STEPS = 160


def exact_run(starts: tuple[int, ...], steps: int) -> tuple[list[list[int]], int]:
    """Trigger masks (T1/T2/T3 bits, START at step 1) per step and robot of the self-triggered rule
    with the prop fresh-information law, in exact degrees; and how many T1 evaluations were exact ties."""
    count = len(starts)
    theta = [Fraction(angle) for angle in starts]
    memory_minus = [Fraction(0)] * count  # remembered neighbour angles (unwrapped, robot-local)
    memory_plus = [Fraction(0)] * count
    age_minus, age_plus = [0] * count, [0] * count
    masks: list[list[int]] = []
    ties = 0

    def neighbours(i: int) -> tuple[Fraction, Fraction]:
        before, after = theta[(i - 1) % count], theta[(i + 1) % count]
        return theta[i] - (theta[i] - before) % 360, theta[i] + (after - theta[i]) % 360

    for step in range(1, steps + 1):
        mask, moves = [], []
        for i in range(count):
            if step > 1:
                age_minus[i] += 1
                age_plus[i] += 1
            m_minus = theta[i] - (theta[i] - memory_minus[i]) % 360
            m_plus = theta[i] + (memory_plus[i] - theta[i]) % 360
            ubd = OMEGA * (age_minus[i] + age_plus[i]) * DT / 4
            offset = (m_minus + 2 * theta[i] + m_plus) / 4 - theta[i]
            if step == 1:
                reasons = int(Trigger.START)
            else:
                bound = max(abs(offset), SIGMA)
                ties += ubd == bound
                reasons = (int(Trigger.UNCERTAINTY) * (ubd >= bound)
                           + int(Trigger.SUCCESSOR) * (m_plus - OMEGA * age_plus[i] * DT <= theta[i])
                           + int(Trigger.PREDECESSOR) * (m_minus + OMEGA * age_minus[i] * DT >= theta[i]))
            mask.append(reasons)
            if reasons:
                exact_minus, exact_plus = neighbours(i)
                memory_minus[i], memory_plus[i] = exact_minus, exact_plus
                age_minus[i] = age_plus[i] = 0
                error = (exact_minus + 2 * theta[i] + exact_plus) / 4 - theta[i]
                moves.append(DT * max(-OMEGA, min(OMEGA, error)))
            else:
                magnitude = min(max(abs(offset) - ubd, Fraction(0)), OMEGA * DT)
                moves.append(magnitude if offset > 0 else -magnitude)
        theta = [angle + move for angle, move in zip(theta, moves, strict=True)]
        masks.append(mask)
    return masks, ties


def test_ties_in_the_trigger_are_decided_as_in_exact_degrees():
    for starts in STARTS:
        expected, ties = exact_run(starts, STEPS)
        assert ties > 0, "these starts must produce exact ties in T1, or the test proves nothing"
        history = engine.run(scenario_from(starts), steps=STEPS, record_positions=False)
        np.testing.assert_array_equal(history.triggers[:, 0], np.array(expected, dtype=np.uint8))


def scenario_from(starts: tuple[int, ...]) -> Scenario:
    """paper-stationary at the coarse settings, the robots starting at ``starts`` (degrees about the target)."""
    spec = load_scenario("paper-stationary", dt=float(DT), sigma_deg=float(SIGMA), omega_max_deg=float(OMEGA),
                         max_steps=STEPS).spec
    team = msgspec.structs.replace(spec.team, angles_deg=[float(angle) for angle in starts])
    return resolve(msgspec.structs.replace(spec, team=team))
