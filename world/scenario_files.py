"""Loading scenarios: a TOML file or a shipped scenario name, decoded and type-checked into a spec."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import msgspec

from ringtrack.world.scenario_errors import ScenarioError, explain_validation
from ringtrack.world.scenario_schema import ScenarioSpec

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


def parse_scenario(text: bytes | str, label: str = "scenario") -> ScenarioSpec:
    """Decode and type-check TOML into a :class:`ScenarioSpec`."""
    try:
        raw = msgspec.toml.decode(text)
    except msgspec.DecodeError as error:
        raise ScenarioError(f"{label}: not valid TOML ({error}); fix the syntax") from None
    target = raw.get("target")
    if isinstance(target, dict):
        target.setdefault("motion", "stationary")
    _move_strategy_name(raw, label)
    try:
        return msgspec.convert(raw, ScenarioSpec)
    except msgspec.ValidationError as error:
        raise ScenarioError(f"{label}: {explain_validation(str(error), raw)}") from None


def _move_strategy_name(raw: dict, label: str) -> None:
    """Accept the strategy's name where scenarios gave it before ``[strategy]`` existed, ``[control]
    strategy``, as ``[strategy] name`` (a strategy's parameters have no old place to come from)."""
    control, section = raw.get("control"), raw.get("strategy", {})
    if not (isinstance(control, dict) and "strategy" in control and isinstance(section, dict)):
        return
    if "name" in section:
        raise ScenarioError(f"{label}: control.strategy and strategy.name both name the strategy; "
                            "keep strategy.name only")
    raw["strategy"] = {"name": control.pop("strategy"), **section}
