"""Scenarios resolved into run parameters: :class:`Scenario` (SI units), :func:`resolve` (cross-field
rules, the fault plan and its radio), :func:`apply_overrides` and :func:`load_scenario`, the entry point.

The file format is :mod:`ringtrack.world.scenario_schema`, reading files and shipped names
:mod:`ringtrack.world.scenario_files`, the wording of invalid values
:mod:`ringtrack.world.scenario_errors`; their public names are importable from here too. Every
problem is reported as one :class:`ScenarioError` line naming the key and the fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from ringtrack.bus.faults import NO_FAULTS, FaultPlan, LinkRates, Outage, link
from ringtrack.bus.keys import participants
from ringtrack.bus.radio import Radio
from ringtrack.world.geometry import ConvexRegion, FloatArray, RegionError
from ringtrack.world.params import DEFAULT_STRATEGY, ControlParams, EstimationParams, StrategyChoice
from ringtrack.world.ring import ring_gaps
from ringtrack.world.scenario_errors import ScenarioError, explain_validation
from ringtrack.world.scenario_files import parse_scenario, read_scenario_text, shipped_scenarios
from ringtrack.world.scenario_schema import LinkFaultSpec, ScenarioSpec
from ringtrack.world.target import Stationary, matched_process_noise

__all__ = [
    "OverrideError",
    "Scenario",
    "ScenarioError",
    "ScenarioSpec",
    "apply_overrides",
    "load_scenario",
    "parse_scenario",
    "read_scenario_text",
    "resolve",
    "shipped_scenarios",
]

MIN_START_GAP = 1e-6  # rad; closer starts count as co-located
START_DRAWS = 100  # random starts drawn before spreading one out (large teams)
TARGET_MARGIN = 1e-6  # fraction of D_out a target path must stay inside the region
DEFAULT_OMEGA_MAX_DEG = 1.0  # deg/s, when a scenario gives neither omega_max_deg nor v_max


@dataclass(frozen=True)
class Scenario:
    """A validated scenario with everything in SI units (metres, seconds, radians).

    ``target`` is the target's position at step 1; :meth:`target_path` gives every step's.
    ``strategy`` is the ``[strategy]`` section: the strategy's name and its parameters as given
    (checked by the strategy itself: :func:`ringtrack.agents.strategy.check_strategy`).
    """

    spec: ScenarioSpec
    region: ConvexRegion
    target: FloatArray
    control: ControlParams
    estimation: EstimationParams
    threshold: float  # rad, convergence threshold on Cerr
    v_max: float | None  # m/s cap on boundary speed in the world, None: no cap
    faults: FaultPlan = NO_FAULTS
    communication_range: float | None = None  # m, r_c; None: unlimited
    strategy: StrategyChoice = StrategyChoice()

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def seed(self) -> int:
        return self.spec.seed

    @property
    def robots(self) -> int:
        return self.spec.team.robots

    @property
    def max_steps(self) -> int:
        return self.spec.control.max_steps

    @property
    def moving(self) -> bool:
        return not isinstance(self.spec.target, Stationary)

    @property
    def centralized(self) -> bool:
        """Whether a fusion centre estimates the target for the team (``estimation.mode``)."""
        return self.estimation.mode == "centralized"

    def participants(self, monitor: bool = True) -> set[str]:
        """Every participant a run of this scenario starts with: the world, the robots, the fusion
        centre of centralized estimation and (``monitor``) the monitor (:func:`bus.keys.participants`)."""
        return participants(range(self.robots), self.centralized, monitor)

    def target_path(self, seed: int, steps: int) -> FloatArray:
        """Target positions (metres) at steps 1..``steps``, shape (steps, 2)."""
        margin = TARGET_MARGIN * self.region.outer_diameter
        return self.spec.target.path(steps, self.control.dt, self.region, seed, margin)

    def start_angles(self, seed: int) -> FloatArray:
        """Initial angles (radians about the target, CCW ring order): the scenario's explicit
        ``team.angles_deg`` or ``robots`` sorted uniform draws from ``numpy.random.default_rng(seed)``,
        redrawn while two lie within ``MIN_START_GAP``. A team so large that draws keep colliding
        (thousands of robots) gets its last draw spread out: every gap grown by ``2 MIN_START_GAP``
        and the ring shrunk to fit."""
        if self.spec.team.angles_deg is not None:
            return np.deg2rad(np.asarray(self.spec.team.angles_deg, dtype=float))
        rng = np.random.default_rng(seed)
        for _ in range(START_DRAWS):
            angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, self.robots))
            if ring_gaps(angles).min() > MIN_START_GAP:
                return angles
        spare = 2.0 * np.pi - 2.0 * self.robots * MIN_START_GAP
        return angles[0] + (angles - angles[0]) * spare / (2.0 * np.pi) + 2.0 * MIN_START_GAP * np.arange(self.robots)

    def start_positions(self, seed: int) -> FloatArray:
        """Initial boundary points (metres, shape ``(robots, 2)``) for ``seed``."""
        return self.region.boundary_point(self.start_angles(seed), self.target)

    def to_toml(self) -> bytes:
        """The scenario as TOML, so a run folder can record exactly what ran."""
        return msgspec.toml.encode(self.spec)


def load_scenario(name_or_path: str, **overrides: Any) -> Scenario:
    """Read, validate and resolve a scenario; ``overrides`` are ``section.key``-free keyword pairs
    such as ``strategy="constant"``, ``robots=8``, ``seed=3``, ``max_steps=500``,
    ``strategy_parameters={"push_gate": 1.5}`` (see :func:`apply_overrides`)."""
    text, label = read_scenario_text(name_or_path)
    spec = parse_scenario(text, label)
    return resolve(apply_overrides(spec, **overrides), label)


# Override name -> (section or None for the top level, key).
OVERRIDABLE: dict[str, tuple[str | None, str]] = {
    "strategy": ("strategy", "name"),
    "law": ("control", "law"),
    "dt": ("control", "dt"),
    "omega_max_deg": ("control", "omega_max_deg"),
    "v_max": ("control", "v_max"),
    "sigma_deg": ("control", "sigma_deg"),
    "threshold_deg": ("control", "threshold_deg"),
    "max_steps": ("control", "max_steps"),
    "robots": ("team", "robots"),
    "estimation": ("estimation", "mode"),
    "drop": ("faults", "drop"),
    "duplicate": ("faults", "duplicate"),
    "communication_range": ("limits", "communication_range"),
    "seed": (None, "seed"),
    "name": (None, "name"),
}
# The override that sets keys of [strategy] (a mapping key -> value, merged into the section).
STRATEGY_PARAMETERS = "strategy_parameters"


class OverrideError(ScenarioError):
    """An override's value is invalid. The message is ``section.key: problem; fix``; ``name`` (the
    override), ``value``, ``path`` (``section.key``) and ``problem`` (the rest) let a command line
    word it by its own flag."""

    def __init__(self, name: str, value: Any, path: str, problem: str) -> None:
        super().__init__(f"{path}{problem}")
        self.name, self.value, self.path, self.problem = name, value, path, problem


def apply_overrides(spec: ScenarioSpec, **overrides: Any) -> ScenarioSpec:
    """Replace keys of a spec (``OVERRIDABLE`` names, e.g. command-line flags, and
    ``strategy_parameters``, a mapping merged into ``[strategy]``: see :func:`_strategy_section`);
    ``None`` values are ignored. The
    result is validated like a file, so a bad value gets the same one-line error as a bad key,
    raised as :class:`OverrideError` naming the override.

    A ``robots`` override that no longer matches explicit ``team.angles_deg`` replaces them by a
    seeded random start (``start_angles``).
    """
    sections: dict[str | None, dict[str, Any]] = {}
    for name, value in overrides.items():
        if value is None:
            continue
        if name == STRATEGY_PARAMETERS:
            sections.setdefault("strategy", {}).update(value)
            continue
        if name not in OVERRIDABLE:
            known = ", ".join([*OVERRIDABLE, STRATEGY_PARAMETERS])
            raise ScenarioError(f"unknown override {name!r}; use one of {known}")
        section, key = OVERRIDABLE[name]
        sections.setdefault(section, {})[key] = value
    team = sections.get("team", {})
    angles = spec.team.angles_deg
    if "robots" in team and angles is not None and len(angles) != team["robots"]:
        team["angles_deg"] = None  # explicit start of another team size: use a seeded random start
    replaced: dict[str, Any] = dict(sections.pop(None, {}))
    if "strategy" in sections:
        replaced["strategy"] = _strategy_section(dict(spec.strategy), sections.pop("strategy"))
    for section, values in sections.items():
        assert section is not None
        replaced[section] = msgspec.structs.replace(getattr(spec, section), **values)
    merged = msgspec.structs.replace(spec, **replaced)
    raw = msgspec.to_builtins(merged)
    try:
        return msgspec.convert(raw, ScenarioSpec)
    except msgspec.ValidationError as error:
        text = explain_validation(str(error), raw)
        for name, value in overrides.items():
            if name == STRATEGY_PARAMETERS:
                continue  # worded by the key it names, strategy.KEY
            section, key = OVERRIDABLE[name]
            path = f"{section}.{key}" if section else key
            if value is not None and text.startswith(f"{path}:"):
                raise OverrideError(name, value, path, text[len(path):]) from None
        raise ScenarioError(text) from None


def _strategy_section(section: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """``[strategy]`` with the keys ``given`` by overrides: a ``name`` replaces the strategy (the
    section's plain keys, the named strategy's parameters, go with it; its ``[strategy.OTHER]``
    tables stay); plain keys set the parameters of the strategy that runs; a table ``OTHER``
    is merged into ``[strategy.OTHER]`` and, where OTHER is the strategy that runs, set as plain
    keys too, so that an override wins over the file's."""
    name = given.get("name", section.get("name", DEFAULT_STRATEGY))
    if name != section.get("name", DEFAULT_STRATEGY):
        section = {key: value for key, value in section.items() if isinstance(value, dict)}
    for key, value in given.items():
        if isinstance(value, dict):
            section[key] = {**section.get(key, {}), **value}
            if key == name:
                section.update(value)
        else:
            section[key] = value
    return section


def resolve(spec: ScenarioSpec, label: str = "scenario") -> Scenario:
    """Check the cross-field rules of a spec and build the :class:`Scenario`."""
    try:
        region = ConvexRegion.from_vertices(spec.region.vertices)
        spec.target.check(region, TARGET_MARGIN * region.outer_diameter)
    except RegionError as error:
        raise ScenarioError(f"{label}: {error}") from None
    target = spec.target.path(1, spec.control.dt, region, spec.seed, 0.0)[0]
    team = spec.team
    if team.angles_deg is not None:
        if len(team.angles_deg) != team.robots:
            raise ScenarioError(
                f"{label}: team.angles_deg has {len(team.angles_deg)} angles for team.robots = {team.robots};"
                " give one angle per robot"
            )
        gaps = ring_gaps(np.deg2rad(team.angles_deg))
        if gaps.min() <= MIN_START_GAP:
            raise ScenarioError(f"{label}: team.angles_deg has co-located robots; give distinct angles")
        if abs(gaps.sum() - 2.0 * np.pi) > 1e-9:
            raise ScenarioError(
                f"{label}: team.angles_deg must go once counter-clockwise around the target; sort them"
            )
    control = spec.control
    omega_deg = control.omega_max_deg
    if omega_deg is None and control.v_max is not None:
        try:
            omega = region.omega_max(control.v_max, control.dt, target)
        except RegionError as error:
            raise ScenarioError(f"{label}: {error}") from None
    else:
        omega = math.radians(omega_deg if omega_deg is not None else DEFAULT_OMEGA_MAX_DEG)
    threshold_deg = control.threshold_deg if control.threshold_deg is not None else 0.1 * team.robots
    params = ControlParams(
        omega_max=omega,
        dt=control.dt,
        sigma=math.radians(control.sigma_deg),
        law=control.law,
    )
    estimation = spec.estimation
    if estimation.mode == "known" and not isinstance(spec.target, Stationary):
        raise ScenarioError(
            f"{label}: estimation.mode = 'known' needs a stationary target; use 'centralized' or 'decentralized'"
        )
    if estimation.prior == "trilateration" and estimation.mode != "centralized":
        raise ScenarioError(
            f"{label}: estimation.prior = 'trilateration' needs the centralized mode (one robot has one range);"
            " use 'truth' or [x, y]"
        )
    strategy = _strategy_choice(spec, label)
    # Only an estimating team needs the inscribed radius (the Chebyshev centre: a solve for every triple
    # of edges). A margin below the vertices' mean's distance to the nearest edge (at most the inscribed
    # radius) passes without it.
    room = float(region.heights(region.vertices.mean(axis=0)).min())
    if (estimation.mode != "known" and estimation.margin >= room
            and estimation.margin >= (inscribed_radius := region.inner_diameter / 2.0)):
        raise ScenarioError(
            f"{label}: estimation.margin {estimation.margin:g} m leaves no room: the region's inscribed radius "
            f"(D_in / 2) is {inscribed_radius:.4g} m; give a margin below it (default 0.1)"
        )
    if not isinstance(estimation.prior, str):
        try:
            region.require_interior(estimation.prior, "estimation.prior")
        except RegionError as error:
            raise ScenarioError(f"{label}: {error}") from None
    return Scenario(
        spec=spec,
        region=region,
        target=target,
        control=params,
        estimation=EstimationParams(
            mode=estimation.mode,
            range_sigma=estimation.range_sigma,
            process_noise=(matched_process_noise(spec.target, control.dt, team.robots, estimation.range_sigma)
                           if estimation.process_noise == "auto" else estimation.process_noise),
            prior=estimation.prior if isinstance(estimation.prior, str) else (estimation.prior[0], estimation.prior[1]),
            prior_variance=estimation.prior_variance,
            fusion=estimation.fusion,
            criterion=estimation.criterion,
            margin=estimation.margin,
        ),
        threshold=math.radians(threshold_deg),
        v_max=control.v_max,
        faults=_fault_plan(spec, label, _radio(spec, label)),
        communication_range=spec.limits.communication_range,
        strategy=strategy,
    )


def _strategy_choice(spec: ScenarioSpec, label: str) -> StrategyChoice:
    """The ``[strategy]`` section: its name checked to be a name at all (whether it names a strategy,
    and the strategy's parameters, are the strategy's to check: :mod:`ringtrack.agents.strategy`)."""
    values = {key: value for key, value in spec.strategy.items() if not isinstance(value, dict)}
    tables = {key: value for key, value in spec.strategy.items() if isinstance(value, dict)}
    name = values.pop("name", DEFAULT_STRATEGY)
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"{label}: strategy.name: expected a registered strategy's name or the path of a .py "
                            "file, e.g. \"self\"; fix the value")
    return StrategyChoice.of(name, values, tables)


def _radio(spec: ScenarioSpec, label: str) -> Radio:
    """The ``[radio]`` section in SI units; the disk model needs the range it is the disk of."""
    section = spec.radio
    if section.model == "disk" and spec.limits.communication_range is None:
        raise ScenarioError(f"{label}: radio.model = 'disk' needs limits.communication_range (r_c, metres); set it")
    return Radio(
        model=section.model,
        tx_power_dbm=section.tx_power_dbm,
        path_loss_d0_db=section.path_loss_d0_db,
        d0_m=section.d0_m,
        exponent=section.exponent,
        shadowing_db=section.shadowing_db,
        sensitivity_dbm=section.sensitivity_dbm,
        transition_db=section.transition_db,
        e_elec=section.e_elec_nj_per_bit * 1e-9,
        eps_amp=section.eps_amp_pj_per_bit_m2 * 1e-12,
        overhead_bytes=section.overhead_bytes,
        latency_s=section.latency_ms / 1000.0,
        bandwidth_bps=section.bandwidth_kbps * 1000.0,
    )


def _fault_plan(spec: ScenarioSpec, label: str, radio: Radio) -> FaultPlan:
    """The ``[faults]`` section resolved (robot ids checked, outage windows in steps) with the
    links' ``radio``."""
    faults, robots, dt = spec.faults, spec.team.robots, spec.control.dt

    def pair(value: tuple[int, int], key: str) -> frozenset[int]:
        a, b = value
        if not (0 <= a < robots and 0 <= b < robots) or a == b:
            raise ScenarioError(f"{label}: {key} {list(value)} must name two different robots 0..{robots - 1}")
        return link(a, b)

    def rates(override: LinkFaultSpec | None = None) -> LinkRates:
        def pick(name: str) -> float:
            value = None if override is None else getattr(override, name)
            return getattr(faults, name) if value is None else value

        return LinkRates(pick("drop"), pick("duplicate"), pick("delay_ms") / 1000.0, pick("jitter_ms") / 1000.0)

    outages = []
    for index, outage in enumerate(faults.outages):
        key = f"faults.outages[{index}]"
        no_steps = outage.from_step is None and outage.to_step is None
        no_seconds = outage.from_s is None and outage.to_s is None
        if outage.from_step is not None and outage.to_step is not None and no_seconds:
            first, last = outage.from_step, outage.to_step
        elif outage.from_s is not None and outage.to_s is not None and no_steps:
            first, last = (int(math.floor(seconds / dt)) + 1 for seconds in (outage.from_s, outage.to_s))
        else:
            raise ScenarioError(f"{label}: {key} needs from_step and to_step, or from_s and to_s (simulated seconds)")
        if first > last:
            raise ScenarioError(f"{label}: {key} ends before it starts; give from <= to")
        if not outage.links:
            raise ScenarioError(f"{label}: {key}.links is empty; name the links that go down, e.g. [[0, 1]]")
        links = frozenset(pair(value, f"{key}.links") for value in outage.links)
        outages.append(Outage(links, first, last))
    overrides = {pair(entry.between, f"faults.links[{index}].between"): rates(entry)
                 for index, entry in enumerate(faults.links)}
    seed = spec.seed if faults.seed is None else faults.seed
    return FaultPlan(seed=seed, default=rates(), links=overrides, outages=tuple(outages), radio=radio)
