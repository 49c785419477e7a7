"""Error wording of scenarios: msgspec's validation messages turned into ``section.key: problem; fix``."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal, get_args, get_origin, get_type_hints

from ringtrack.world.scenario_schema import ScenarioSpec
from ringtrack.world.schema import COORDINATE_LIMIT, Coordinate, Probability, Spec

# Sections where scenarios once gave a strategy's parameters (control.plan_horizon, estimation.push_gate).
STRATEGY_KEYS_WERE_IN = ("control", "estimation")


class ScenarioError(ValueError):
    """A scenario cannot be used; the message is one line naming the key and the fix."""


def explain_validation(message: str, raw: Any) -> str:
    """Turn msgspec's message into ``section.key: problem; fix`` (``raw`` is the decoded TOML, which
    says which variant of a tagged section such as ``[target]`` was meant)."""
    where = re.search(r" - at `\$\.?(.*)`$", message)
    path = where.group(1) if where else ""
    body = message[: where.start()] if where else message
    unknown = re.match(r"Object contains unknown field `(.+)`", body)
    if unknown:
        allowed = ", ".join(_fields_at(path, raw))
        place = f"[{path}]" if path else "top level"
        moved = "; a strategy's own parameters go in [strategy]" if path in STRATEGY_KEYS_WERE_IN else ""
        return f"unknown key {unknown.group(1)!r} in {place}; allowed keys: {allowed}{moved}"
    missing = re.match(r"Object missing required field `(.+)`", body)
    if missing:
        key = f"{path}.{missing.group(1)}" if path else missing.group(1)
        return f"{key} is missing; add it"
    if "[...]" in path:  # a value of a plain table ([strategy]): name its key
        base, _, rest = path.partition("[...]")
        key = base + _wrong_key(_type_at(base, raw)[1], nested=bool(rest))
        return f"{key}: expected a boolean, a number or a string, got `{body.rpartition('`, got `')[2]}; fix the value"
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


def _wrong_key(table: Any, nested: bool) -> str:
    """``.key`` of the first value of a plain table that is not a boolean, a number, a string nor a
    table; with ``nested``, ``.table.key`` of the first such value in one of its tables."""
    for key, value in table.items() if isinstance(table, dict) else []:
        if not nested and isinstance(value, list):
            return f".{key}"
        for inner, entry in value.items() if nested and isinstance(value, dict) else []:
            if isinstance(entry, list | dict):
                return f".{key}.{inner}"
    return ""


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
    literals = [option for option in (found, *get_args(found)) if get_origin(option) is Literal]
    return [value for option in literals for value in get_args(option)]
