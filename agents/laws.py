"""The constant and the self-triggered midpoint laws (docs/algorithms.md sections 3 and 4).

Pure functions of numpy arrays that broadcast over robots and trials: the in-process engine calls
them for a whole team at once, a robot process for itself with scalars (:mod:`world.elementwise`:
the same bits, without numpy's cost per call). Angles are radians (robot ``i``'s local
frame, see :mod:`world.ring`), ``omega_max`` is rad/s, ``dt`` and ages in seconds are
``age_steps * dt``; ages are kept as integer step counts so that trigger ties do not drift.

Symbols: ``theta`` own angle; ``m_minus``/``m_plus`` remembered predecessor/successor angles;
``c_minus``/``c_plus`` their ages in steps; ``gV`` the guaranteed midpoint; ``ubd`` the bound on
``|V - gV|``; ``sigma`` the trigger tolerance (radians).
"""

from __future__ import annotations

import enum
from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

from ringtrack.world.elementwise import SCALARS, Values, clip
from ringtrack.world.params import ControlParams
from ringtrack.world.ring import midpoint

# Angles closer than this (radians) are equal in the trigger's comparisons: far above the rounding
# error of a step (~1e-15 rad) and far below any meaningful angle (a micro-degree is 1.7e-8 rad).
TIE_RAD = 1e-12


class Trigger(enum.IntFlag):
    """Why a robot polled its neighbours in a step (a bit mask; 0 means it did not)."""

    UNCERTAINTY = 1  # T1: ubd >= max(|gV - theta|, sigma)
    SUCCESSOR = 2  # T2: m_plus - phi_plus <= theta (order with the CCW neighbour not guaranteed)
    PREDECESSOR = 4  # T3: m_minus + phi_minus >= theta
    SCHEDULE = 8  # constant strategy: every step
    START = 16  # step 1: every robot starts with exact information
    UNKNOWN = 32  # nothing is known of a reachable neighbour (it changed, or its answer was lost)


# A Trigger mask per robot: an int array, or one robot's integer (a numpy integer, which a type
# checker knows only as an int).
Mask: TypeAlias = NDArray[np.int64] | int

# The bits as plain ints, for the laws evaluated every step (a flag member's lookup costs more than
# the arithmetic it feeds).
UNCERTAINTY_BIT, SUCCESSOR_BIT, PREDECESSOR_BIT = (int(Trigger.UNCERTAINTY), int(Trigger.SUCCESSOR),
                                                   int(Trigger.PREDECESSOR))
START_BIT, UNKNOWN_BIT = int(Trigger.START), int(Trigger.UNKNOWN)


def uncertainty_bound(c_minus: Values, c_plus: Values, params: ControlParams) -> Values:
    """``ubd = omega_max (tau_minus + tau_plus) / 4`` (radians), ``tau = c * dt``."""
    return params.omega_max * (c_minus + c_plus) * params.dt / 4.0


def guarded_step(offset: Values, ubd: Values, max_step: float) -> Values:
    """Non-triggered motion towards ``theta + offset`` (``offset = gV - theta``, radians).

    Moves ``|offset| - ubd`` clipped to ``[0, max_step]`` in the direction of ``offset``: full speed
    while farther than ``ubd + max_step``, stop within ``ubd``. With ``ubd = 0`` it is the deadbeat law.
    """
    return np.sign(offset) * clip(np.abs(offset) - ubd, 0.0, max_step)


def fresh_step(offset: Values, params: ControlParams) -> Values:
    """Motion with exact neighbour information towards ``theta + offset`` (``offset = V - theta``)."""
    if params.law == "prop":
        return params.dt * clip(offset, -params.omega_max, params.omega_max)
    return guarded_step(offset, 0.0, params.max_step)


def trigger_reasons(
    theta: Values,
    m_minus: Values,
    m_plus: Values,
    c_minus: Values,
    c_plus: Values,
    params: ControlParams,
    tolerance: Values | None = None,
) -> Mask:
    """Evaluate the self-triggered rule at the start of a step, before moving.

    Returns a :class:`Trigger` mask per robot: T1 ``ubd >= max(|gV - theta|, sigma)``,
    T2 ``m_plus - omega tau_plus <= theta``, T3 ``m_minus + omega tau_minus >= theta``. Each
    comparison is tie-robust: sides within ``TIE_RAD`` count as equal, so equality (which the
    inequalities include) is decided as in exact arithmetic, not by rounding error. Ties are frequent
    at coarse settings (e.g. dt 0.5 s, omega_max 1 deg/s, sigma 0.1 deg: every quantity is a multiple
    of 1/8 degree, exact in degrees but not in radians). ``tolerance`` (radians, per robot) stands
    for ``sigma`` where a strategy widens it (default ``params.sigma``).
    """
    reach_minus = params.omega_max * c_minus * params.dt
    reach_plus = params.omega_max * c_plus * params.dt
    ubd = uncertainty_bound(c_minus, c_plus, params)
    sigma = params.sigma if tolerance is None else tolerance
    return set_trigger_reasons(theta, m_minus, m_plus, reach_minus, reach_plus, ubd, sigma)


def set_trigger_reasons(
    theta: Values,
    m_minus: Values,
    m_plus: Values,
    phi_minus: Values,
    phi_plus: Values,
    ubd: Values,
    sigma: Values,
) -> Mask:
    """T1-T3 of :func:`trigger_reasons` for neighbours known to lie in the prediction sets
    ``[m_- - phi_-, m_- + phi_-]`` and ``[m_+ - phi_+, m_+ + phi_+]`` (radians, robot-local frame),
    with ``ubd`` the bound on ``|V - gV|``: T1 ``ubd >= max(|gV - theta|, sigma)``,
    T2 ``m_+ - phi_+ <= theta``, T3 ``m_- + phi_- >= theta``, each tie-robust within ``TIE_RAD``."""
    offset = midpoint(m_minus, theta, m_plus) - theta
    t1 = ubd >= clip(np.abs(offset), sigma) - TIE_RAD
    t2 = m_plus - phi_plus <= theta + TIE_RAD
    t3 = m_minus + phi_minus >= theta - TIE_RAD
    return t1 * UNCERTAINTY_BIT + t2 * SUCCESSOR_BIT + t3 * PREDECESSOR_BIT


def angular_step(
    theta: Values,
    m_minus: Values,
    m_plus: Values,
    c_minus: Values,
    c_plus: Values,
    fresh: Values,
    params: ControlParams,
) -> Values:
    """The step ``Delta theta`` (radians, CCW positive) a robot applies this step.

    Where ``fresh`` (its memory was just refreshed, ages 0) the fresh-information law moves towards
    the exact midpoint; elsewhere the guarded law moves towards ``gV`` and stops within ``ubd``.
    """
    offset = midpoint(m_minus, theta, m_plus) - theta
    ubd = uncertainty_bound(c_minus, c_plus, params)
    if isinstance(fresh, SCALARS):  # one robot: only the law that applies
        return fresh_step(offset, params) if fresh else guarded_step(offset, ubd, params.max_step)
    return np.where(fresh, fresh_step(offset, params), guarded_step(offset, ubd, params.max_step))


REASONS = {  # short codes, explained in the legend line
    Trigger.START: "start",
    Trigger.SCHEDULE: "every",
    Trigger.UNCERTAINTY: "T1",
    Trigger.SUCCESSOR: "T2",
    Trigger.PREDECESSOR: "T3",
    Trigger.UNKNOWN: "unk",
}


def reason_text(mask: int) -> str:
    """Short codes of the trigger conditions in a mask, joined by "+" ("-" for none)."""
    names = [name for flag, name in REASONS.items() if mask & flag]
    return "+".join(names) if names else "-"
