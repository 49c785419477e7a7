"""The ``relay`` strategy: self-triggered polls whose tolerance follows the estimate, every message
carrying ranges (docs/algorithms.md section 20)."""

from __future__ import annotations

from typing import Any

from ringtrack.agents.laws import UNCERTAINTY_BIT, Mask, trigger_reasons
from ringtrack.agents.relay import bearing_sd, ranges_wanted
from ringtrack.agents.strategy import SelfTriggered, StrategyParameter
from ringtrack.world.elementwise import choose, clip


class RelayedRanges(SelfTriggered):
    """The self-triggered rule with two changes that read the robot's own estimate: T1's tolerance
    is at least the standard deviation of the robot's bearing from its estimate of the target (it
    does not poll to place itself more finely than it knows where it stands), and a robot also
    polls (T1) while its estimate's variance exceeds ``terr_ratio^2`` times what a filter taking
    every robot's range every step settles to (it asks for the ranges it lacks). Requests and
    replies carry the ranges their sender holds (:mod:`agents.relay`)."""

    name = "relay"
    summary = "self-triggered with a tolerance from the estimate, every request and reply carrying ranges"
    label = "relayed ranges"
    estimation = "decentralized"
    relays = True
    reads_uncertainty = True
    parameters = (
        StrategyParameter("terr_ratio", float, 1.2, units="", gt=1.0,
                          help="poll while the estimate's expected error exceeds this many times that of a "
                          "filter taking every robot's range every step"),
    )
    terr_ratio: float

    def triggers(self, controller: Any) -> Mask:
        uncertainty = controller.uncertainty
        if uncertainty is None:  # nothing known of the estimate: the paper's rule
            return super().triggers(controller)
        covariance = uncertainty.covariance
        tolerance = clip(bearing_sd(controller.own_position, controller.centre, covariance), controller.params.sigma)
        reasons = trigger_reasons(controller.theta, controller.m_minus, controller.m_plus, controller.predecessor_age,
                                  controller.successor_age, controller.params, tolerance)
        wanted = ranges_wanted(covariance, uncertainty.steady_variance, self.terr_ratio)
        return reasons | choose(wanted, UNCERTAINTY_BIT, 0)
