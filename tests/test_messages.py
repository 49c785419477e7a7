"""Message schemas, keys and validation (bus/messages.py, bus/keys.py, bus/participant.py)."""

from __future__ import annotations

import asyncio

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bus.keys import Keys, robot_index
from bus.messages import (
    SCHEMA,
    Command,
    End,
    Measurement,
    Rejected,
    Reply,
    Request,
    Stats,
    Tick,
    decode,
    encode,
)
from bus.participant import Delivery, Participant

RUN = 0x1234ABCD
KEYS = Keys(RUN)
ROBOTS = 6

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
points = st.tuples(finite, finite)
robots = st.integers(0, ROBOTS - 1)
steps = st.integers(1, 10**6)
nonces = st.integers(0, 2**32 - 1)


def messages() -> st.SearchStrategy:
    covariance = st.one_of(st.none(), st.tuples(finite, finite, finite))
    return st.one_of(
        st.builds(lambda s, t, r, p, z: Measurement(SCHEMA, RUN, s, t, r, p, z), steps, finite, robots, points,
                  st.one_of(st.none(), finite)),
        st.builds(lambda s, r, g, m, o, a, c, v: Command(SCHEMA, RUN, s, r, g, m, o, a, c, v), steps, robots, points,
                  st.integers(0, 31), finite, st.tuples(steps, steps), points, covariance),
        st.builds(lambda s, a, b, n: Request(SCHEMA, RUN, s, a, b, n), steps, robots, robots, nonces),
        st.builds(lambda s, a, b, n, p, m, v: Reply(SCHEMA, RUN, s, a, b, n, p, m, v), steps, robots, robots, nonces,
                  points, st.one_of(st.none(), points), covariance),
        st.builds(lambda s, t, ps, p: Tick(SCHEMA, RUN, s, t, ps, p, list(range(len(ps)))), steps, finite,
                  st.lists(points, max_size=ROBOTS), points),
        st.builds(lambda s, why, w: End(SCHEMA, RUN, s, why, w), steps, st.text(max_size=20), finite),
    )


def route_of(message):
    from bus.messages import endpoints

    source, destination = endpoints(message)
    return KEYS.parse(KEYS.data(destination or "all", source, message.kind))


@given(messages())
def test_every_message_round_trips(message) -> None:
    assert decode(encode(message), route_of(message), RUN, ROBOTS) == message


def test_neighbour_messages_are_compact() -> None:
    request = Request(SCHEMA, RUN, 123_456, 4, 5, 2**32 - 1)
    reply = Reply(SCHEMA, RUN, 123_456, 5, 4, 2**32 - 1, (12.345678901234, -3.21))
    assert len(encode(request)) <= 20
    assert len(encode(reply)) <= 42  # 2 floats of 9 bytes; absent belief fields cost 1 byte each


def test_rejection_reasons() -> None:
    request = Request(SCHEMA, RUN, 3, 1, 2, 42)
    route = KEYS.parse(KEYS.data("r2", "r1", "request"))
    cases = {
        "malformed": (b"\x93\x01\x02", route),
        "schema": (encode(Request(SCHEMA + 1, RUN, 3, 1, 2, 42)), route),
        "foreign": (encode(Request(SCHEMA, RUN + 1, 3, 1, 2, 42)), route),
        "route": (encode(request), KEYS.parse(KEYS.data("r2", "r1", "reply"))),
    }
    for reason, (payload, where) in cases.items():
        with pytest.raises(Rejected) as raised:
            decode(payload, where, RUN, ROBOTS)
        assert raised.value.reason == reason
    with pytest.raises(Rejected) as raised:  # a sender its key does not name
        decode(encode(request), KEYS.parse(KEYS.data("r2", "r3", "request")), RUN, ROBOTS)
    assert raised.value.reason == "sender"
    impossible = Request(SCHEMA, RUN, 3, 9, 2, 42)
    with pytest.raises(Rejected) as raised:  # robot 9 does not exist in a team of 6
        decode(encode(impossible), KEYS.parse(KEYS.data("r2", "r9", "request")), RUN, ROBOTS)
    assert raised.value.reason == "sender"
    with pytest.raises(Rejected) as raised:  # a key of another run's prefix has no route in this run
        decode(encode(request), KEYS.parse(Keys(RUN + 1).data("r2", "r1", "request")), RUN, ROBOTS)
    assert raised.value.reason == "foreign"


@given(st.binary(max_size=200))
def test_random_bytes_are_rejected_never_raised(payload: bytes) -> None:
    route = KEYS.parse(KEYS.data("r2", "r1", "request"))
    try:
        message = decode(payload, route, RUN, ROBOTS)
    except Rejected as rejection:
        assert rejection.reason in ("malformed", "schema", "foreign", "route", "sender")
    else:  # astronomically unlikely, but then it must be a valid request of this run
        assert isinstance(message, Request) and message.run == RUN


@given(st.lists(st.one_of(st.integers(-(2**63), 2**63 - 1), finite, st.text(max_size=5), st.none()), max_size=9))
def test_well_formed_msgpack_of_the_wrong_shape_is_rejected(fields: list) -> None:
    route = KEYS.parse(KEYS.data("world", "r1", "command"))
    with pytest.raises(Rejected):
        decode(msgspec.msgpack.encode([2, *fields]), route, RUN, ROBOTS)


def test_participant_counts_rejections_and_accepts_the_rest() -> None:
    loop = asyncio.new_event_loop()
    try:
        participant = Participant(session=None, keys=KEYS, name="monitor", robots=ROBOTS, loop=loop)  # type: ignore[arg-type]
        good = Request(SCHEMA, RUN, 3, 1, 2, 42)
        batch = [
            (KEYS.data("r2", "r1", "request"), encode(good)),
            (KEYS.data("r2", "r1", "request"), b"garbage"),
            (KEYS.data("r2", "r1", "request"), encode(Request(SCHEMA, 7, 3, 1, 2, 42))),
            ("ringtrack/ffffffff/r2/r1/request", encode(good)),
            (KEYS.data("r2", "r1", "request"), encode(Stats(SCHEMA, RUN, "r1", False, [], [], {}, 0))),
        ]
        accepted = participant.accept(batch)
    finally:
        loop.close()
    assert [event.message for event in accepted if isinstance(event, Delivery)] == [good]
    assert dict(participant.counter.rejected) == {"malformed": 1, "foreign": 2, "route": 1}
    assert participant.counter.received_messages[("request", "r1", "r2")] == 1


def test_keys_keep_runs_apart() -> None:
    assert KEYS.prefix == "ringtrack/1234abcd"
    assert KEYS.parse("ringtrack/00000001/r2/r1/request") is None
    assert KEYS.parse(KEYS.data("r2", "r1", "request")).kind == "request"
    assert (robot_index("r12"), robot_index("world"), robot_index("r01"), robot_index("r-1")) == (12, None, None, None)
