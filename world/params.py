"""The plain parameter records a scenario resolves into (SI units: metres, seconds, radians).

They hold numbers and choices only, no behaviour beyond derived quantities, so that the world (which
resolves scenarios) and the agents (which act on them) share one definition.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

FreshLaw = Literal["prop", "deadbeat"]
Mode = Literal["known", "centralized", "decentralized"]
Criterion = Literal["trace", "det"]
PLAN_HORIZON = 10  # default H of the plan strategy, steps (README: chosen by measurement)

@dataclass(frozen=True)
class ControlParams:
    """Parameters of the midpoint laws.

    ``omega_max`` rad/s, ``dt`` s, ``sigma`` rad; ``strategy`` a registered strategy's name ("self",
    "constant", "plan", "belief", ...) or the path of a Python file defining one (:mod:`agents.strategy`);
    ``law`` is the fresh-information law ("prop": ``dt * sat(e)``, "deadbeat": ``sign(e) min(omega dt, |e|)``);
    ``plan_horizon`` the most steps ahead a plan reply describes (``H``, steps).
    """

    omega_max: float
    dt: float
    sigma: float = 0.0
    strategy: str = "self"
    law: FreshLaw = "prop"
    plan_horizon: int = PLAN_HORIZON

    @property
    def max_step(self) -> float:
        """Largest angular step in one step, ``omega_max * dt`` (radians)."""
        return self.omega_max * self.dt



@dataclass(frozen=True)
class EstimationParams:
    """How the team estimates the target (section ``[estimation]`` of a scenario).

    ``range_sigma`` (m) and ``process_noise`` (m^2 per step) model the filters' R and Q;
    ``prior`` is "truth" (the target's position at step 1, as the authors), "trilateration"
    (centralized; see :class:`Estimator`) or a point; ``prior_variance`` (m^2) sets P0 of "truth"
    and of a point; decentralized robots fuse their neighbours' beliefs with joint CI ("ci") or
    pairwise ("sequential"), minimising "trace" or "det"; every estimate is kept ``margin`` metres
    inside the region (the filters' own means, not only what a robot steers by). ``push_gate`` is
    the gate ``g`` of the belief strategy's pushes (a Mahalanobis distance, dimensionless).
    """

    mode: Mode = "known"
    range_sigma: float = 0.2
    process_noise: float = 0.2
    prior: str | tuple[float, float] = "truth"
    prior_variance: float = 1.0
    fusion: Literal["ci", "sequential"] = "ci"
    criterion: Criterion = "trace"
    margin: float = 0.1
    push_gate: float = 2.0
