"""The scenario file's TOML schema: one msgspec struct per section, unknown keys refused.

A scenario file looks like::

    name = "paper-stationary"
    seed = 0
    [region]
    vertices = [[3, 7], [8, 17], [5, 26], [1, 22]]   # metres, either orientation
    [target]
    position = [4, 20]          # metres, inside the region; or motion = "circle" | "random_walk" | "waypoints"
    [team]
    robots = 6
    angles_deg = [69.9, 75.1, 83.1, 108.1, 170.1, 303.9]   # optional; else a seeded random start
    [strategy]
    name = "belief"            # "self" (default) | "constant" | "plan" | "belief" | path/to/strategy.py
    push_gate = 2.0            # the named strategy's own parameters (`ringtrack strategies` lists them)
    [strategy.plan]            # parameters of a strategy run in its place (--strategy plan)
    plan_horizon = 10
    [control]
    law = "prop"               # fresh-information law: "prop" | "deadbeat"
    dt = 0.1                   # s
    omega_max_deg = 1.0        # deg/s; or v_max (m/s) and omega_max is derived
    sigma_deg = 0.06           # trigger tolerance, deg
    threshold_deg = 0.6        # convergence threshold on Cerr, deg (default 0.1 N)
    max_steps = 3000
    [sensing]
    range_sigma = 0.2          # m, noise of the measured ranges
    range = 30.0               # m, sensing range r_s (default: unlimited)
    [estimation]
    mode = "known"             # "known" (robots know the stationary target) | "centralized" | "decentralized"
    range_sigma = 0.2          # m, the filters' model of the range noise
    process_noise = 0.2        # m^2 per step, Q = q I; "auto": fitted to the target's motion
    prior = "truth"            # "truth" | "trilateration" (centralized) | [x, y]
    prior_variance = 1.0       # m^2, P0 = p I
    fusion = "ci"              # decentralized: joint CI of own + both neighbours | "sequential" pairwise
    criterion = "trace"        # CI weights minimise "trace" or "det" of the fused covariance
    margin = 0.1               # m: every estimate is kept this far inside the region (below D_in / 2)
    [limits]
    communication_range = 5.0  # m, r_c: links longer than this are down (default: unlimited)
    [faults]                   # robot-to-robot links; seeded by seed (default: the scenario's)
    drop = 0.2                 # probability a message is lost
    duplicate = 0.0            # probability a message arrives twice
    delay_ms = 0.0             # wall delay, with +- jitter_ms
    [[faults.links]]           # per-link override: between = [0, 1], drop = 0.5, ...
    [[faults.outages]]         # links down: links = [[2, 3], [5, 0]], from_step = 100, to_step = 300
    [radio]                    # robot-to-robot links' loss with distance, energy, realtime latency
    model = "log-distance"     # "ideal" (default) | "disk" (limits.communication_range) | "log-distance"
    tx_power_dbm = 0.0         # transmit power
    path_loss_d0_db = 40.05    # PL(d0): free space at 1 m, 2.4 GHz
    d0_m = 1.0                 # reference distance, m
    exponent = 3.0             # path-loss exponent n
    shadowing_db = 4.0         # sd of the shadowing X, dB, drawn per link and step
    sensitivity_dbm = -85.0    # receiver sensitivity S: half the packets are lost at S
    transition_db = 1.0        # width w of the logistic PER(P_r) = 1 / (1 + exp((P_r - S) / w))
    e_elec_nj_per_bit = 50.0   # first-order radio: electronics, nJ/bit (transmit and receive)
    eps_amp_pj_per_bit_m2 = 100.0  # amplifier, pJ/bit/m^2 (transmit)
    overhead_bytes = 0         # per message, added to its encoded size (headers of the link layer)
    latency_ms = 0.0           # realtime, disk or log-distance: base latency of every message
    bandwidth_kbps = 250.0     # realtime, disk or log-distance: adds 8 bytes / bandwidth

The radio's formulas are in :mod:`ringtrack.bus.radio`.

``[strategy]`` is a plain table: ``name`` (default "self") and the named strategy's own parameters,
which only the strategy knows (it declares them: :mod:`ringtrack.agents.strategy`), so here they are
checked only to be a boolean, a number or a string. A table ``[strategy.OTHER]`` holds the
parameters of strategy OTHER for runs where it replaces the named one (``--strategy OTHER``, an
experiment comparing strategies): ``[strategy.belief] push_gate = 1.5``. A scenario written before
the section existed may still give the name as ``[control] strategy``
(:func:`ringtrack.world.scenario_files.parse_scenario`).

A new section is a ``Spec`` struct here plus a field of :class:`ScenarioSpec`; what it means for a run
is resolved in :func:`ringtrack.world.scenario.resolve`, and an invalid value is worded by
:mod:`ringtrack.world.scenario_errors` from the struct's annotations (nothing to add there).
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from ringtrack.world.params import StrategyValue
from ringtrack.world.schema import Finite, NonNegative, Point, Positive, Probability, Spec
from ringtrack.world.target import TargetSpec

# [strategy]: name and the named strategy's parameters, plus a [strategy.OTHER] table per other strategy.
StrategySection = dict[str, StrategyValue | dict[str, StrategyValue]]


class RegionSpec(Spec, frozen=True):
    vertices: list[Point]


MAX_ROBOTS = 100_000


class TeamSpec(Spec, frozen=True):
    robots: Annotated[int, msgspec.Meta(ge=3, le=MAX_ROBOTS)] = 6
    angles_deg: list[Finite] | None = None


class ControlSpec(Spec, frozen=True):
    law: Literal["prop", "deadbeat"] = "prop"
    dt: Positive = 0.1
    omega_max_deg: Positive | None = None
    v_max: Positive | None = None
    sigma_deg: NonNegative = 0.0
    threshold_deg: Positive | None = None
    max_steps: Annotated[int, msgspec.Meta(ge=1)] = 3000


class SensingSpec(Spec, frozen=True):
    range_sigma: NonNegative = 0.0
    range: Positive | None = None


class EstimationSpec(Spec, frozen=True):
    mode: Literal["known", "centralized", "decentralized"] = "known"
    range_sigma: Positive = 0.2
    process_noise: NonNegative | Literal["auto"] = 0.2
    prior: Literal["truth", "trilateration"] | Point = "truth"
    prior_variance: Positive = 1.0
    fusion: Literal["ci", "sequential"] = "ci"
    criterion: Literal["trace", "det"] = "trace"
    margin: NonNegative = 0.1  # m: every estimate is kept this far inside the region


class LimitsSpec(Spec, frozen=True):
    communication_range: Positive | None = None


class LinkFaultSpec(Spec, frozen=True):
    between: tuple[int, int]
    drop: Probability | None = None
    duplicate: Probability | None = None
    delay_ms: NonNegative | None = None
    jitter_ms: NonNegative | None = None


class OutageSpec(Spec, frozen=True):
    links: list[tuple[int, int]]
    from_step: Annotated[int, msgspec.Meta(ge=1)] | None = None
    to_step: Annotated[int, msgspec.Meta(ge=1)] | None = None
    from_s: NonNegative | None = None
    to_s: NonNegative | None = None


class FaultsSpec(Spec, frozen=True):
    seed: Annotated[int, msgspec.Meta(ge=0)] | None = None
    drop: Probability = 0.0
    duplicate: Probability = 0.0
    delay_ms: NonNegative = 0.0
    jitter_ms: NonNegative = 0.0
    links: list[LinkFaultSpec] = []
    outages: list[OutageSpec] = []


class RadioSpec(Spec, frozen=True):
    model: Literal["ideal", "disk", "log-distance"] = "ideal"
    tx_power_dbm: Finite = 0.0
    path_loss_d0_db: Finite = 40.05
    d0_m: Positive = 1.0
    exponent: Positive = 3.0
    shadowing_db: NonNegative = 4.0
    sensitivity_dbm: Finite = -85.0
    transition_db: Positive = 1.0
    e_elec_nj_per_bit: NonNegative = 50.0
    eps_amp_pj_per_bit_m2: NonNegative = 100.0
    overhead_bytes: Annotated[int, msgspec.Meta(ge=0, le=65536)] = 0
    latency_ms: NonNegative = 0.0
    bandwidth_kbps: Positive = 250.0


class ScenarioSpec(Spec, kw_only=True, frozen=True):
    region: RegionSpec
    target: TargetSpec
    name: str = "scenario"
    seed: Annotated[int, msgspec.Meta(ge=0)] = 0
    team: TeamSpec = TeamSpec()
    # [strategy]: name (a registered name or a .py file) and the strategy's own parameters.
    strategy: StrategySection = {}
    control: ControlSpec = ControlSpec()
    sensing: SensingSpec = SensingSpec()
    estimation: EstimationSpec = EstimationSpec()
    limits: LimitsSpec = LimitsSpec()
    faults: FaultsSpec = FaultsSpec()
    radio: RadioSpec = RadioSpec()
