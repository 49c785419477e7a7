"""Fuzzing every message decoder and the scenario loader: whatever arrives, a counted drop
(:class:`Rejected` with a known reason) or a one-line error (:class:`ScenarioError`), never a
traceback."""

from __future__ import annotations

import tomllib
from typing import Any

import msgspec
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.bus.keys import FUSION, MONITOR, WORLD, Keys, Route
from ringtrack.bus.messages import KINDS, REJECT_REASONS, Rejected, decode, encode
from ringtrack.world.scenario import parse_scenario, resolve
from ringtrack.world.scenario_errors import ScenarioError
from tests.helpers import examples
from tests.test_messages import messages, route_of

RUN = 0x1234ABCD
ROBOTS = 6
KEYS = Keys(RUN)
NAMES = [WORLD, MONITOR, FUSION, "all", *(f"r{robot}" for robot in range(ROBOTS)), "r6", "r-1", "x"]
SHIPPED = "scenarios/authors-moving.toml"

# msgpack-able values of any shape: what a forger can put in a well-formed payload.
values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(allow_nan=True),
              st.text(max_size=8), st.binary(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=4), inner, max_size=4)),
    max_leaves=30)


def decoded_or_rejected(payload: bytes, route: Route) -> None:
    """Decoding ``payload`` on ``route`` gives a message of this run or a rejection with a known reason."""
    try:
        message = decode(payload, route, RUN, ROBOTS)
    except Rejected as rejection:
        assert rejection.reason in REJECT_REASONS
        assert "\n" not in str(rejection)
    else:
        assert message.run == RUN and message.kind == route.kind


@settings(max_examples=examples(400))
@given(st.sampled_from(sorted(KINDS)), st.sampled_from(NAMES), st.sampled_from(NAMES), values)
def test_any_well_formed_payload_on_any_key_is_decoded_or_rejected(kind: str, source: str, destination: str,
                                                                   body: Any) -> None:
    tag = KINDS[kind].__struct_config__.tag
    for payload in (msgspec.msgpack.encode(body), msgspec.msgpack.encode([tag, 1, RUN, body]),
                    msgspec.msgpack.encode([tag, 1, RUN, *(body if isinstance(body, list) else [body])])):
        decoded_or_rejected(payload, Route(destination, source, kind))


@settings(max_examples=examples(300))
@given(messages(), st.data())
def test_every_message_damaged_anyhow_is_decoded_or_rejected(message: Any, data: st.DataObject) -> None:
    payload = bytearray(encode(message))
    route = route_of(message)
    cut = data.draw(st.integers(0, len(payload)))
    decoded_or_rejected(bytes(payload[:cut]), route)  # truncated
    for index in data.draw(st.lists(st.integers(0, len(payload) - 1), max_size=4)):
        payload[index] ^= data.draw(st.integers(1, 255))  # bytes flipped
    decoded_or_rejected(bytes(payload), route)
    decoded_or_rejected(bytes(payload) + data.draw(st.binary(min_size=1, max_size=16)), route)  # padded


def loaded_or_refused(text: str) -> None:
    """Loading a scenario text gives a scenario or a one-line :class:`ScenarioError`."""
    try:
        resolve(parse_scenario(text, "fuzz.toml"), "fuzz.toml")
    except ScenarioError as error:
        assert str(error).startswith("fuzz.toml") and "\n" not in str(error), str(error)


@settings(max_examples=examples(300), deadline=None)
@given(st.text(max_size=300))
def test_any_text_as_a_scenario_is_loaded_or_refused_in_one_line(text: str) -> None:
    loaded_or_refused(text)


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value) if value == value and abs(value) != float("inf") else "nan"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return "[" + ", ".join(_toml(item) for item in value) + "]"


@settings(max_examples=examples(300), deadline=None)
@given(st.data())
def test_a_shipped_scenario_with_any_value_replaced_is_loaded_or_refused_in_one_line(data: st.DataObject) -> None:
    with open(SHIPPED, "rb") as file:
        table = tomllib.load(file)
    section = data.draw(st.sampled_from(sorted(key for key, value in table.items() if isinstance(value, dict))))
    key = data.draw(st.sampled_from(sorted(table[section]) or ["anything"]))
    value = data.draw(st.one_of(st.integers(-(10**12), 10**12), st.floats(), st.text(max_size=6), st.booleans(),
                                st.lists(st.one_of(st.integers(-100, 100), st.floats(-1e3, 1e3)), max_size=5),
                                st.lists(st.lists(st.floats(-50, 50), min_size=2, max_size=2), max_size=6)))
    table[section][key] = value
    lines = []
    for name, content in table.items():
        if isinstance(content, dict):
            lines.append(f"[{name}]")
            lines += [f"{inner} = {_toml(item)}" for inner, item in content.items() if not isinstance(item, dict)]
        else:
            lines.insert(0, f"{name} = {_toml(content)}")
    loaded_or_refused("\n".join(lines) + "\n")
