"""Scenarios: TOML files validated by msgspec (unknown keys rejected), resolved into run parameters.

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
    [control]
    strategy = "self"          # "self" | "constant"
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
    process_noise = 0.2        # m^2 per step, Q = q I
    prior = "truth"            # "truth" | "trilateration" (centralized) | [x, y]
    prior_variance = 1.0       # m^2, P0 = p I
    fusion = "ci"              # decentralized: joint CI of own + both neighbours | "sequential" pairwise
    criterion = "trace"        # CI weights minimise "trace" or "det" of the fused covariance
    [limits]
    communication_range = 5.0  # m, r_c: links longer than this are down (default: unlimited)
    [faults]                   # robot-to-robot links; seeded by seed (default: the scenario's)
    drop = 0.2                 # probability a message is lost
    duplicate = 0.0            # probability a message arrives twice
    delay_ms = 0.0             # wall delay, with +- jitter_ms
    [[faults.links]]           # per-link override: between = [0, 1], drop = 0.5, ...
    [[faults.outages]]         # links down: links = [[2, 3], [5, 0]], from_step = 100, to_step = 300
    [radio]                    # loss with distance, energy, realtime latency: see world/radio.py

Every problem is reported as one :class:`ScenarioError` line naming the key and the fix.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin, get_type_hints

import msgspec
import numpy as np

from ringtrack.bus.faults import NO_FAULTS, FaultPlan, LinkRates, Outage, link
from ringtrack.world.geometry import ConvexRegion, FloatArray, RegionError
from ringtrack.world.params import ControlParams, EstimationParams
from ringtrack.world.radio import RadioSpec, with_radio
from ringtrack.world.ring import ring_gaps
from ringtrack.world.schema import COORDINATE_LIMIT, Coordinate, Finite, NonNegative, Point, Positive, Probability, Spec
from ringtrack.world.target import Stationary, TargetSpec

MIN_START_GAP = 1e-6  # rad; closer starts count as co-located
START_DRAWS = 100  # random starts drawn before spreading one out (large teams)
TARGET_MARGIN = 1e-6  # fraction of D_out a target path must stay inside the region


class ScenarioError(ValueError):
    """A scenario cannot be used; the message is one line naming the key and the fix."""


class RegionSpec(Spec):
    vertices: list[Point]


MAX_ROBOTS = 100_000


class TeamSpec(Spec):
    robots: Annotated[int, msgspec.Meta(ge=3, le=MAX_ROBOTS)] = 6
    angles_deg: list[Finite] | None = None


class ControlSpec(Spec):
    strategy: Literal["self", "constant"] = "self"
    law: Literal["prop", "deadbeat"] = "prop"
    dt: Positive = 0.1
    omega_max_deg: Positive | None = None
    v_max: Positive | None = None
    sigma_deg: NonNegative = 0.0
    threshold_deg: Positive | None = None
    max_steps: Annotated[int, msgspec.Meta(ge=1)] = 3000


class SensingSpec(Spec):
    range_sigma: NonNegative = 0.0
    range: Positive | None = None


class EstimationSpec(Spec):
    mode: Literal["known", "centralized", "decentralized"] = "known"
    range_sigma: Positive = 0.2
    process_noise: NonNegative = 0.2
    prior: Literal["truth", "trilateration"] | Point = "truth"
    prior_variance: Positive = 1.0
    fusion: Literal["ci", "sequential"] = "ci"
    criterion: Literal["trace", "det"] = "trace"


class LimitsSpec(Spec):
    communication_range: Positive | None = None


class LinkFaultSpec(Spec):
    between: tuple[int, int]
    drop: Probability | None = None
    duplicate: Probability | None = None
    delay_ms: NonNegative | None = None
    jitter_ms: NonNegative | None = None


class OutageSpec(Spec):
    links: list[tuple[int, int]]
    from_step: Annotated[int, msgspec.Meta(ge=1)] | None = None
    to_step: Annotated[int, msgspec.Meta(ge=1)] | None = None
    from_s: NonNegative | None = None
    to_s: NonNegative | None = None


class FaultsSpec(Spec):
    seed: Annotated[int, msgspec.Meta(ge=0)] | None = None
    drop: Probability = 0.0
    duplicate: Probability = 0.0
    delay_ms: NonNegative = 0.0
    jitter_ms: NonNegative = 0.0
    links: list[LinkFaultSpec] = []
    outages: list[OutageSpec] = []


class ScenarioSpec(Spec, kw_only=True):
    region: RegionSpec
    target: TargetSpec
    name: str = "scenario"
    seed: Annotated[int, msgspec.Meta(ge=0)] = 0
    team: TeamSpec = TeamSpec()
    control: ControlSpec = ControlSpec()
    sensing: SensingSpec = SensingSpec()
    estimation: EstimationSpec = EstimationSpec()
    limits: LimitsSpec = LimitsSpec()
    faults: FaultsSpec = FaultsSpec()
    radio: RadioSpec = RadioSpec()


DEFAULT_OMEGA_MAX_DEG = 1.0


@dataclass(frozen=True)
class Scenario:
    """A validated scenario with everything in SI units (metres, seconds, radians).

    ``target`` is the target's position at step 1; :meth:`target_path` gives every step's.
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


# ---------------------------------------------------------------------------- loading
SCENARIO_PACKAGE = "ringtrack.scenarios"


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``scenarios/``."""
    folder = resources.files(SCENARIO_PACKAGE)
    return sorted(entry.name[:-5] for entry in folder.iterdir() if entry.name.endswith(".toml"))


def read_scenario_text(name_or_path: str) -> tuple[bytes, str]:
    """Bytes and a display name of a scenario given as a file path or a shipped scenario name."""
    path = Path(name_or_path)
    if path.is_file():
        return path.read_bytes(), str(path)
    shipped = resources.files(SCENARIO_PACKAGE) / f"{name_or_path.removesuffix('.toml')}.toml"
    if shipped.is_file():
        return shipped.read_bytes(), f"{shipped.name}"
    raise ScenarioError(
        f"scenario {name_or_path!r} is neither a file nor a shipped scenario; use a path or one of: "
        + ", ".join(shipped_scenarios())
    )


def load_scenario(name_or_path: str, **overrides: Any) -> Scenario:
    """Read, validate and resolve a scenario; ``overrides`` are ``section.key``-free keyword pairs
    such as ``strategy="constant"``, ``robots=8``, ``seed=3``, ``max_steps=500`` (see
    :func:`apply_overrides`)."""
    text, label = read_scenario_text(name_or_path)
    spec = parse_scenario(text, label)
    return resolve(apply_overrides(spec, **overrides), label)


def parse_scenario(text: bytes | str, label: str = "scenario") -> ScenarioSpec:
    """Decode and type-check TOML into a :class:`ScenarioSpec`."""
    try:
        raw = msgspec.toml.decode(text)
    except msgspec.DecodeError as error:
        raise ScenarioError(f"{label}: not valid TOML ({error}); fix the syntax") from None
    target = raw.get("target")
    if isinstance(target, dict):
        target.setdefault("motion", "stationary")
    try:
        return msgspec.convert(raw, ScenarioSpec)
    except msgspec.ValidationError as error:
        raise ScenarioError(f"{label}: {_explain_validation(str(error), raw)}") from None


# Override name -> (section or None for the top level, key).
OVERRIDABLE: dict[str, tuple[str | None, str]] = {
    "strategy": ("control", "strategy"),
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


FLAGS = {"max_steps": "--steps"}  # command-line flags of overrides not spelled like their name


def apply_overrides(spec: ScenarioSpec, **overrides: Any) -> ScenarioSpec:
    """Replace keys of a spec (command-line flags); ``None`` values are ignored. The result is
    validated like a file, so a bad flag value gets the same one-line error as a bad key.

    A ``robots`` override that no longer matches explicit ``team.angles_deg`` replaces them by a
    seeded random start (``start_angles``).
    """
    sections: dict[str | None, dict[str, Any]] = {}
    for name, value in overrides.items():
        if value is None:
            continue
        if name not in OVERRIDABLE:
            raise ScenarioError(f"unknown override {name!r}; use one of {', '.join(OVERRIDABLE)}")
        section, key = OVERRIDABLE[name]
        sections.setdefault(section, {})[key] = value
    team = sections.get("team", {})
    angles = spec.team.angles_deg
    if "robots" in team and angles is not None and len(angles) != team["robots"]:
        team["angles_deg"] = None  # explicit start of another team size: use a seeded random start
    replaced: dict[str, Any] = dict(sections.pop(None, {}))
    for section, values in sections.items():
        assert section is not None
        replaced[section] = msgspec.structs.replace(getattr(spec, section), **values)
    merged = msgspec.structs.replace(spec, **replaced)
    raw = msgspec.to_builtins(merged)
    try:
        return msgspec.convert(raw, ScenarioSpec)
    except msgspec.ValidationError as error:
        text = _explain_validation(str(error), raw)
        for name, value in overrides.items():  # a bad flag value is named by its flag
            section, key = OVERRIDABLE[name]
            path = f"{section}.{key}" if section else key
            if value is not None and text.startswith(f"{path}:"):
                text = f"{FLAGS.get(name, '--' + name.replace('_', '-'))} {value} ({path}){text[len(path):]}"
        raise ScenarioError(text) from None


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
        strategy=control.strategy,
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
            process_noise=estimation.process_noise,
            prior=estimation.prior if isinstance(estimation.prior, str) else tuple(estimation.prior),
            prior_variance=estimation.prior_variance,
            fusion=estimation.fusion,
            criterion=estimation.criterion,
            clamp_margin=TARGET_MARGIN * region.outer_diameter,
        ),
        threshold=math.radians(threshold_deg),
        v_max=control.v_max,
        faults=with_radio(_fault_plan(spec, label), spec.radio, spec.limits.communication_range, label),
        communication_range=spec.limits.communication_range,
    )


def _fault_plan(spec: ScenarioSpec, label: str) -> FaultPlan:
    """The ``[faults]`` section resolved: robot ids checked, outage windows in steps."""
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
        by_steps = (outage.from_step, outage.to_step)
        by_seconds = (outage.from_s, outage.to_s)
        if None not in by_steps and by_seconds == (None, None):
            first, last = by_steps
        elif None not in by_seconds and by_steps == (None, None):
            first, last = (int(math.floor(seconds / dt)) + 1 for seconds in by_seconds)
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
    return FaultPlan(seed=seed, default=rates(), links=overrides, outages=tuple(outages))


# ---------------------------------------------------------------------------- error text
def _explain_validation(message: str, raw: Any) -> str:
    """Turn msgspec's message into ``section.key: problem; fix`` (``raw`` is the decoded TOML, which
    says which variant of a tagged section such as ``[target]`` was meant)."""
    where = re.search(r" - at `\$\.?(.*)`$", message)
    path = where.group(1) if where else ""
    body = message[: where.start()] if where else message
    unknown = re.match(r"Object contains unknown field `(.+)`", body)
    if unknown:
        allowed = ", ".join(_fields_at(path, raw))
        place = f"[{path}]" if path else "top level"
        return f"unknown key {unknown.group(1)!r} in {place}; allowed keys: {allowed}"
    missing = re.match(r"Object missing required field `(.+)`", body)
    if missing:
        key = f"{path}.{missing.group(1)}" if path else missing.group(1)
        return f"{key} is missing; add it"
    key = path or "scenario"
    kinds = _number_kinds(_type_at(path, raw)[0]) if body.startswith("Expected `float`") else []
    if Probability in kinds:
        return f"{key}: expected a probability in [0, 1]; fix the value"
    if Coordinate in kinds:
        return f"{key}: expected a coordinate in metres within +-{COORDINATE_LIMIT:,.0f}; fix the value"
    if body.startswith("Expected `float`") and ("e+300" in body or body.endswith("0.0")):
        sign = " > 0" if "> 0.0" in body else " >= 0" if ">= 0.0" in body else ""
        return f"{key}: expected a finite number{sign}; fix the value"
    if body.startswith(("Invalid enum value", "Invalid value")):
        choices = ", ".join(repr(choice) for choice in _choices_at(path, raw))
        return f"{key}: {body[0].lower()}{body[1:]}; use one of {choices}"
    return f"{key}: {body[0].lower()}{body[1:]}; fix the value"


def _number_kinds(annotation: Any) -> list[Any]:
    """The checked number types (``Probability``, ``Coordinate``, ...) an annotation holds, looking
    into unions, lists and tuples (a path's list indices are not resolved)."""
    if get_origin(annotation) is Annotated:
        return [annotation]
    return [kind for argument in get_args(annotation) for kind in _number_kinds(argument)]


def _structs(annotation: Any) -> list[type[Spec]]:
    return [c for c in (annotation, *get_args(annotation)) if isinstance(c, type) and issubclass(c, Spec)]


def _struct_for(annotation: Any, section: Any) -> type[Spec] | None:
    """The struct an annotation names; for a tagged union, the member the raw ``section`` is tagged as."""
    members = _structs(annotation)
    for member in members:
        config = member.__struct_config__
        if config.tag_field and isinstance(section, dict) and section.get(config.tag_field) == config.tag:
            return member
    return members[0] if members else None


def _type_at(path: str, raw: Any) -> tuple[Any, Any]:
    """The annotation at a dotted path of the spec and the raw value there."""
    found: Any = ScenarioSpec
    section = raw
    for part in filter(None, re.sub(r"\[\d+\]", "", path).split(".")):
        owner = _struct_for(found, section)
        if owner is None:
            return None, None
        found = get_type_hints(owner, include_extras=True).get(part)
        section = section.get(part) if isinstance(section, dict) else None
    return found, section


def _fields_at(path: str, raw: Any) -> list[str]:
    """Keys allowed in the section at a dotted path (with its tag key, for a tagged section)."""
    owner = _struct_for(*_type_at(path, raw))
    if owner is None:
        return []
    tag_field = owner.__struct_config__.tag_field
    return ([tag_field] if tag_field else []) + list(owner.__struct_fields__)


def _choices_at(path: str, raw: Any) -> list[Any]:
    """Allowed values at a dotted path: the strings of a ``Literal`` (also inside a union) or, for
    a tag key, the variants' tags."""
    parent, _, key = path.rpartition(".")
    owner_annotation, section = _type_at(parent, raw)
    tagged = [member.__struct_config__ for member in _structs(owner_annotation)]
    if any(config.tag_field == key for config in tagged):
        return [config.tag for config in tagged]
    found, _ = _type_at(path, raw)
    return [value for option in (found, *get_args(found)) if get_origin(option) is Literal for value in get_args(option)]
