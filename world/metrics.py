"""Metrics of a run (docs/algorithms.md section 5). Cerr and thresholds are in degrees.

* ``Cerr_true(k) = sum_i |V_i(k) - theta_i(k)|`` from true positions about the true target (the paper's
  constant-strategy Cerr);
* ``Cerr_memory(k) = sum_i |gV_i(k) - theta_i(k)|`` from each robot's memory before it polls in step
  k (the paper's self-triggered Cerr);
* the paper's ``Cerr`` of a run is ``Cerr_memory`` for the self-triggered strategy (and any other
  that remembers) and ``Cerr_true`` for the constant one, as the strategy says
  (``Strategy.cerr``, a :data:`CerrSource`; :func:`strategy_cerr`); a step where a
  live robot's offset is unknown (a realtime robot that sent no command in time) has no
  ``Cerr_memory`` (NaN), never a zero error;
* ``Ctime = min{k >= 1 : Cerr(k) < threshold}`` (1-based; 0 here when it never happens), the one
  rule :func:`converged` every convergence decision uses (engine, world process, run logs);
* ``Terr(k)`` the mean over robots of the distance from the centre each robot steered about to the
  true target (metres), over the robots whose centre is known (:func:`target_error`);
* ``Com-bar = sum_i com(i, Ctime) / (N Ctime)``, ``com(i, k)`` the steps ``<= k`` in which robot i polled.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.world.geometry import ConvexRegion, FloatArray, angle_of
from ringtrack.world.ring import midpoint_errors, successor_values

# Which Cerr is the paper's Cerr of a strategy's run: "memory" (Cerr_memory: the robots' own
# guaranteed offsets) or "true" (Cerr_true: true positions about the true target).
CerrSource = Literal["memory", "true"]
CERR_SOURCES: tuple[CerrSource, ...] = ("memory", "true")


TeamSum = Callable[[NDArray], NDArray]  # per-robot values -> each team's sum over its robots


def convergence_error(offsets: ArrayLike, team_sum: TeamSum | None = None) -> FloatArray:
    """``sum_i |offset_i|`` over the last axis (or each team's, as ``team_sum`` adds them up),
    offsets in radians, result in degrees."""
    magnitudes = np.abs(offsets)
    # np.sum's reduction, without its wrapper
    return np.rad2deg(np.add.reduce(magnitudes, axis=-1) if team_sum is None else team_sum(magnitudes))


def true_offsets(positions: ArrayLike, target: ArrayLike) -> FloatArray:
    """``V_i - theta_i`` (radians) of a whole ring (axis -2 of ``positions``) about the true target."""
    return midpoint_errors(angle_of(positions, np.asarray(target)[..., None, :]))


def true_cerr(positions: ArrayLike, target: ArrayLike) -> FloatArray:
    """``Cerr_true`` (degrees) of a whole ring (axis -2 of ``positions``, metres) about ``target``."""
    return convergence_error(true_offsets(positions, target))


def memory_cerr(offsets: ArrayLike, live: ArrayLike | None = None, team_sum: TeamSum | None = None) -> FloatArray:
    """``Cerr_memory`` (degrees) from the robots' ``gV - theta`` (radians, robots on the last axis,
    or teams added up by ``team_sum``; NaN where unknown) over the ``live`` robots (a boolean mask;
    default: every robot): NaN where any live robot's offset is unknown, so missing values never
    count as zero error."""
    offsets = np.asarray(offsets, dtype=float)
    if live is not None:
        offsets = np.where(live, offsets, 0.0)  # a robot out of the ring is no part of the sum
    return convergence_error(offsets, team_sum)


def strategy_cerr(source: CerrSource, cerr_memory: ArrayLike, cerr_true: ArrayLike) -> FloatArray:
    """The paper's Cerr of a run (degrees) from the ``source`` its strategy names
    (:attr:`agents.strategy.Strategy.cerr`): ``"true"`` for the constant strategy, whose memory is
    always one step old; ``"memory"`` for the self-triggered strategy and every other that remembers."""
    if source not in CERR_SOURCES:
        raise ValueError(f"Cerr source {source!r}; use one of {', '.join(CERR_SOURCES)}")
    return np.asarray(cerr_true if source == "true" else cerr_memory, dtype=float)


def converged(cerr: ArrayLike, threshold_deg: ArrayLike) -> NDArray[np.bool_]:
    """Whether a step counts as converged: its Cerr (degrees) is known and below ``threshold_deg``
    (one for all, or each run's; an unknown, NaN, Cerr compares below nothing)."""
    return np.asarray(cerr, dtype=float) < threshold_deg


def convergence_step(cerr: ArrayLike, threshold_deg: float) -> NDArray[np.int64]:
    """``Ctime`` per run from ``cerr`` of shape ``(steps, ...)``: first 1-based step that
    :func:`converged`, 0 where none does."""
    below = converged(cerr, threshold_deg)
    return np.where(below.any(axis=0), below.argmax(axis=0) + 1, 0)


def target_error(centres: ArrayLike, target: ArrayLike, squared: bool = False) -> FloatArray:
    """``Terr`` (metres): the mean over robots (axis -2 of ``centres``, NaN rows unknown) of the
    distance from each centre to ``target``; NaN where no robot's centre is known. ``squared``: the
    mean of the squared distances instead (m^2; its root over steps is the estimates' RMSE)."""
    offsets = np.asarray(centres, dtype=float) - np.asarray(target)[..., None, :]
    distances = np.sqrt(offsets[..., 0] * offsets[..., 0] + offsets[..., 1] * offsets[..., 1])  # np.linalg.norm's sum
    if squared:
        distances = distances**2
    known = ~np.isnan(distances)
    count = np.add.reduce(known, axis=-1, dtype=np.int64)  # the sums of ndarray.sum, without its wrapper
    total = np.add.reduce(np.where(known, distances, 0.0), axis=-1)
    return np.divide(total, count, out=np.full(total.shape, np.nan), where=count > 0)


def settled_mean(series: ArrayLike, settle: int) -> float | None:
    """The mean of a per-step ``series`` (steps on axis 0; any other axes too) once the first
    ``settle`` steps are left out (steps ``settle + 1 ..``, 1-based), unknown (NaN) values left out
    too: the settled Cerr (degrees), Terr (metres) or messages per step of a moving-target run, as
    ``experiment moving --settle`` and ``simulate``/``spawn --from-step`` report them. None when no
    such step is known."""
    values = np.asarray(series, dtype=float)[max(settle, 0):]
    known = values[~np.isnan(values)]
    return float(known.mean()) if known.size else None


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
    return communication_rate(communications(triggers, ctime).sum(axis=-1), np.asarray(triggers).shape[-1], ctime)


def communication_rate(polls: ArrayLike, robots: ArrayLike, ctime: ArrayLike) -> FloatArray:
    """Com-bar per run of ``robots`` robots from ``polls``, the polls of its steps ``<= ctime``
    (``sum_i com(i, Ctime)``): ``polls / (N Ctime)``; NaN where the run did not converge."""
    ctime = np.asarray(ctime)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ctime > 0, np.asarray(polls) / (np.asarray(robots) * ctime), np.nan)


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
    gaps = np.mod(successor_values(arc) - arc, region.perimeter)
    return (np.abs(gaps.sum(axis=-1) - region.perimeter) < 1e-9 * region.perimeter) & np.all(gaps > 0, axis=-1)
