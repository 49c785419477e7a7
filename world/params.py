"""The plain parameter records a scenario resolves into (SI units: metres, seconds, radians).

They hold numbers and choices only, no behaviour beyond derived quantities, so that the world (which
resolves scenarios) and the agents (which act on them) share one definition.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

FreshLaw = Literal["prop", "deadbeat"]
Mode = Literal["known", "centralized", "decentralized"]
Criterion = Literal["trace", "det"]
StrategyValue = bool | int | float | str  # a value of a strategy's parameter, as a scenario gives it
DEFAULT_STRATEGY = "self"


StrategyTable = Mapping[str, StrategyValue]
Pairs = tuple[tuple[str, StrategyValue], ...]


@dataclass(frozen=True)
class StrategyChoice:
    """The scenario's ``[strategy]`` section: ``name``, a registered strategy's name or the path of a
    Python file defining one; ``values``, the named strategy's own parameters (the section's other
    plain keys); and ``tables``, the parameters of strategies that run in its place (a
    ``[strategy.OTHER]`` table per strategy name: ``--strategy OTHER``, an experiment comparing
    strategies). Keys are kept as sorted pairs, so that a choice is hashable.

    The world does not know what a strategy's parameters mean: the strategy declares them and checks
    these values when it is built (:mod:`agents.strategy`: units, defaults, bounds)."""

    name: str = DEFAULT_STRATEGY
    values: Pairs = ()
    tables: tuple[tuple[str, Pairs], ...] = ()

    @classmethod
    def of(cls, name: str, values: StrategyTable | None = None,
           tables: Mapping[str, StrategyTable] | None = None) -> StrategyChoice:
        """A choice from a name, the named strategy's parameter values and other strategies' tables."""
        return cls(name, _pairs(values or {}),
                   tuple(sorted((other, _pairs(table)) for other, table in (tables or {}).items())))

    def table(self, name: str) -> dict[str, StrategyValue]:
        """The ``[strategy.NAME]`` table of the strategy called ``name`` (empty when there is none)."""
        return dict(dict(self.tables).get(name, ()))


def _pairs(table: StrategyTable) -> Pairs:
    return tuple(sorted(table.items()))


@dataclass(frozen=True)
class ControlParams:
    """Parameters of the midpoint laws.

    ``omega_max`` rad/s, ``dt`` s, ``sigma`` rad; ``law`` is the fresh-information law ("prop":
    ``dt * sat(e)``, "deadbeat": ``sign(e) min(omega dt, |e|)``). Which strategy runs, and its own
    parameters, are the scenario's :class:`StrategyChoice`.
    """

    omega_max: float
    dt: float
    sigma: float = 0.0
    law: FreshLaw = "prop"

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
    inside the region (the filters' own means, not only what a robot steers by).
    """

    mode: Mode = "known"
    range_sigma: float = 0.2
    process_noise: float = 0.2
    prior: str | tuple[float, float] = "truth"
    prior_variance: float = 1.0
    fusion: Literal["ci", "sequential"] = "ci"
    criterion: Criterion = "trace"
    margin: float = 0.1
