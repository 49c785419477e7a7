"""Metrics of a run (docs/algorithms.md section 5). Cerr and thresholds are in degrees.

* ``Cerr_true(k) = sum_i |V_i(k) - theta_i(k)|`` from true positions about the true target (the paper's
  constant-strategy Cerr);
* ``Cerr_memory(k) = sum_i |gV_i(k) - theta_i(k)|`` from each robot's memory before it polls in step
  k (the paper's self-triggered Cerr);
* ``Ctime = min{k >= 1 : Cerr(k) < threshold}`` (1-based; 0 here when it never happens);
* ``Com-bar = sum_i com(i, Ctime) / (N Ctime)``, ``com(i, k)`` the steps ``<= k`` in which robot i polled.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.geometry import ConvexRegion, FloatArray, angle_of
from ringtrack.world.ring import midpoint_errors


def convergence_error(offsets: ArrayLike) -> FloatArray:
    """``sum_i |offset_i|`` over the last axis, offsets in radians, result in degrees."""
    return np.rad2deg(np.sum(np.abs(offsets), axis=-1))


def true_offsets(positions: ArrayLike, target: ArrayLike) -> FloatArray:
    """``V_i - theta_i`` (radians) of a whole ring (axis -2 of ``positions``) about the true target."""
    return midpoint_errors(angle_of(positions, np.asarray(target)[..., None, :]))


def convergence_step(cerr: ArrayLike, threshold_deg: float) -> NDArray[np.int64]:
    """``Ctime`` per run from ``cerr`` of shape ``(steps, ...)``: first 1-based step with
    ``cerr < threshold_deg``, 0 where it never drops below."""
    below = np.asarray(cerr) < threshold_deg
    return np.where(below.any(axis=0), below.argmax(axis=0) + 1, 0)


def communications(triggers: ArrayLike, until: ArrayLike) -> NDArray[np.int64]:
    """``com(i, until)``: steps ``<= until`` (1-based) in which each robot polled.

    ``triggers`` has shape ``(steps, ..., N)`` (nonzero = polled), ``until`` shape ``(...)``.
    """
    polled = np.asarray(triggers) != 0
    step_number = np.arange(1, polled.shape[0] + 1).reshape((-1,) + (1,) * (polled.ndim - 1))
    within = step_number <= np.asarray(until)[None, ..., None]
    return np.sum(polled & within, axis=0)


def mean_communication_rate(triggers: ArrayLike, ctime: ArrayLike) -> FloatArray:
    """Com-bar per run: ``sum_i com(i, Ctime) / (N Ctime)``; NaN where the run did not converge."""
    ctime = np.asarray(ctime)
    count = communications(triggers, ctime).sum(axis=-1)
    robots = np.asarray(triggers).shape[-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ctime > 0, count / (robots * ctime), np.nan)


def range_information(positions: ArrayLike, target: ArrayLike, sigma_z: float) -> FloatArray:
    """Fisher information ``J = sigma_z^-2 sum_i u_i u_i^T`` (m^-2, shape ``(..., 2, 2)``) of range
    measurements with noise standard deviation ``sigma_z`` (metres) from robots at ``positions``
    (axis -2) about ``target``; ``u_i`` is the unit vector from robot i to the target."""
    bearing = np.asarray(target)[..., None, :] - np.asarray(positions, dtype=float)
    unit = bearing / np.linalg.norm(bearing, axis=-1, keepdims=True)
    return np.einsum("...ni,...nj->...ij", unit, unit) / sigma_z**2


def ring_order_kept(region: ConvexRegion, positions: ArrayLike) -> NDArray[np.bool_]:
    """Whether the robots along axis -2 of ``positions`` (boundary points) are still in strict
    counter-clockwise ring order on the boundary (by arc length; the order is the same seen from any
    interior centre)."""
    arc = region.arc_length(positions)
    gaps = np.mod(np.roll(arc, -1, axis=-1) - arc, region.perimeter)
    return (np.abs(gaps.sum(axis=-1) - region.perimeter) < 1e-9 * region.perimeter) & np.all(gaps > 0, axis=-1)
