"""The ``belief`` strategy: the paper's self-triggered triggers with shared decentralized beliefs.

Each robot runs its own range-only EKF (decentralized estimation). On top of the paper's rule
(T1-T3, and the fusion of the polled neighbours' replied beliefs by covariance intersection):

* mutual exchange: a request carries the requester's belief, and the polled neighbour fuses it by
  CI too, in its next step (no extra message);
* pushes: a robot that does not poll tells both ring neighbours its belief when it has moved far
  from the belief it last told them, ``(x - x_last)^T P_last^-1 (x - x_last) > g^2`` with ``g`` the
  strategy's parameter ``push_gate`` (``[strategy] push_gate``, default 2); what it tells by a
  request counts as told.

A robot fuses what it was told in step ``k - 1`` (pushes and requests' beliefs, each predicted one
step) at one defined point of step ``k``: between its own prediction and its own update, before it
decides; so a lockstep team equals the engine whatever the order in which messages arrive
(docs/algorithms.md section 18).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.estimation import Estimators, Told
from ringtrack.agents.strategy import SelfTriggered, StrategyParameter
from ringtrack.world.geometry import FloatArray
from ringtrack.world.params import EstimationParams


def mahalanobis_squared(mean: FloatArray, last_mean: FloatArray, last_covariance: FloatArray) -> FloatArray:
    """``(x - x_last)^T P_last^-1 (x - x_last)`` over the leading shape (means metres ``S + (2,)``,
    covariances m^2 ``S + (2, 2)``); dimensionless."""
    difference = np.asarray(mean, dtype=float) - np.asarray(last_mean, dtype=float)
    solved = np.linalg.solve(np.asarray(last_covariance, dtype=float), difference[..., None])[..., 0]
    return np.einsum("...i,...i->...", difference, solved)


class SharedBelief(SelfTriggered):
    """Self-triggered polling, beliefs carried by requests and pushed past a Mahalanobis gate."""

    name = "belief"
    summary = "self-triggered, decentralized beliefs shared in requests and pushed past a gate"
    label = "shared beliefs"
    estimation = "decentralized"
    listens = True
    pushes = True
    parameters = (
        StrategyParameter("push_gate", float, 2.0, units="sigmas", gt=0,
                          help="push the belief once it moved this Mahalanobis distance g from the last told "
                          "((x - x_last)^T P_last^-1 (x - x_last) > g^2)"),
    )
    push_gate: float

    def hear(self, estimators: Estimators, positions: ArrayLike, ranges: ArrayLike, told: Told) -> None:
        """Each told belief is a step old: predicted one step (``P + Q``, the filter's own process
        noise) so that it is as uncertain as a belief about this step, it is fused with the robot's
        own prediction by CI, and the robot's own range then updates the fused prior."""
        estimators.measure(positions, ranges, told.predicted(estimators.params.process_noise))

    def wants_push(self, mean: FloatArray, last_mean: FloatArray, last_covariance: FloatArray,
                   params: EstimationParams) -> NDArray[np.bool_]:
        return mahalanobis_squared(mean, last_mean, last_covariance) > self.push_gate**2
