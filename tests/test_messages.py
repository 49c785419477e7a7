"""Message schemas, keys and validation (bus/messages.py, bus/keys.py, bus/participant.py)."""

from __future__ import annotations

import asyncio

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ringtrack.bus.keys import Keys, robot_index
from ringtrack.bus.messages import (
    BOUND,
    NONCE_BASE,
    SCHEMA,
    CarryingReply,
    Command,
    Digest,
    DigestEntry,
    End,
    EndReason,
    Measurement,
    RangeReply,
    RangeRequest,
    Rejected,
    Reply,
    Request,
    Stats,
    Tick,
    compact,
    decode,
    encode,
    number_bytes,
    robot_message_bytes,
)
from ringtrack.bus.participant import Delivery, Participant

RUN = 0x1234ABCD
KEYS = Keys(RUN)
ROBOTS = 6

finite = st.floats(-BOUND, BOUND, width=64)
non_negative = st.floats(0.0, BOUND, width=64)
points = st.tuples(finite, finite)
robots = st.integers(0, ROBOTS - 1)
steps = st.integers(1, 10**6)
nonces = st.integers(0, 2**32 - 1)


def messages() -> st.SearchStrategy:
    late = st.just(2 * 10**6)  # relay messages: of a step after every range they carry and hold
    covariance = st.one_of(st.none(), st.tuples(finite, finite, finite))
    return st.one_of(
        st.builds(lambda s, t, r, p, z: Measurement(SCHEMA, RUN, s, t, r, p, z), steps, non_negative, robots, points,
                  st.one_of(st.none(), non_negative)),
        st.builds(lambda s, r, g, m, o, a, c, v, t: Command(SCHEMA, RUN, s, r, g, m, o, a, c, v, t), steps, robots,
                  points, st.integers(0, 31), finite, st.tuples(steps, steps), points, covariance,
                  st.lists(st.tuples(st.integers(0, 2), robots, st.integers(1, 2), st.integers(0, 10**6)),
                           max_size=8)),
        st.builds(lambda s, a, b, n: Request(SCHEMA, RUN, s, a, b, n), steps, robots, robots, nonces),
        st.builds(lambda s, a, b, n, p, m, v: Reply(SCHEMA, RUN, s, a, b, n, p, m, v), steps, robots, robots, nonces,
                  points, st.one_of(st.none(), points), covariance),
        st.builds(lambda s, a, b, n, known, ranges: RangeRequest(SCHEMA, RUN, s, a, b, n, known, ranges), late,
                  robots, robots, nonces, st.lists(st.integers(10**6, 2 * 10**6 - 1), min_size=ROBOTS,
                                                   max_size=ROBOTS),
                  relayed()),
        st.builds(lambda s, a, b, n, p, known, ranges: RangeReply(SCHEMA, RUN, s, a, b, n, p, None, None, known,
                                                                  ranges),
                  late, robots, robots, nonces, points,
                  st.lists(st.integers(10**6, 2 * 10**6 - 1), min_size=ROBOTS, max_size=ROBOTS), relayed()),
        st.builds(lambda s, t, ps, p, live: Tick(SCHEMA, RUN, s, t, ps, p, live), steps, non_negative,
                  st.lists(points, min_size=ROBOTS, max_size=ROBOTS), points,
                  st.lists(robots, max_size=ROBOTS, unique=True)),
        st.builds(lambda s, why, w: End(SCHEMA, RUN, s, why, w), st.integers(0, 10**6), st.sampled_from(EndReason),
                  non_negative),
        st.builds(lambda entries: Digest(SCHEMA, RUN, entries), st.lists(digest_entries(), max_size=10)),
    )


def relayed() -> st.SearchStrategy:
    """Relayed ranges (source, step, x, y, range or None) of steps no later than any message's."""
    return st.lists(st.tuples(robots, st.integers(1, 10**6), finite, finite, st.one_of(st.none(), non_negative)),
                    max_size=20)


def digest_entries() -> st.SearchStrategy:
    """A step of a digest: its tick (or none: a continuation), measurement sizes and commands."""
    def entry(step: int, tick: bool, t: float, positions: list, target: tuple, live: list, sizes: list,
              commands: list) -> DigestEntry:
        return DigestEntry(step, Tick(SCHEMA, RUN, step, t, positions, target, live) if tick else None, sizes,
                           [(Command(SCHEMA, RUN, step, robot, goal, 0, None, (0, 0), goal), size)
                            for robot, goal, size in commands])
    counts = st.integers(0, 10**4)
    return st.builds(entry, steps, st.booleans(), non_negative, st.lists(points, min_size=ROBOTS, max_size=ROBOTS),
                     points, st.lists(robots, max_size=ROBOTS, unique=True),
                     st.lists(st.tuples(robots, counts), max_size=ROBOTS),
                     st.lists(st.tuples(robots, points, counts), max_size=ROBOTS))


def route_of(message):
    from ringtrack.bus.messages import endpoints

    source, destination = endpoints(message)
    return KEYS.parse(KEYS.data(destination or "all", source, message.kind))


@given(messages())
def test_every_message_round_trips(message) -> None:
    assert decode(encode(message), route_of(message), RUN, ROBOTS) == message


# Well-formed messages carrying one impossible value each: (message, reason it is rejected for).
BAD_VALUES = [
    (Request(SCHEMA, RUN, 0, 1, 2, 42), "malformed"),  # steps are 1-based
    (Request(SCHEMA, RUN, -5, 1, 2, 42), "malformed"),
    (Request(SCHEMA, RUN, 3, 1, 2, -1), "malformed"),  # nonces are 32-bit unsigned
    (Request(SCHEMA, RUN, 3, -1, 2, 42), "sender"),  # a negative robot id
    (Request(SCHEMA, RUN, 3, 1, -7, 42), "sender"),
    (Request(SCHEMA, RUN, 3, 1, 6, 42), "sender"),  # robot 6 of a team of 6
    (Reply(SCHEMA, RUN, 3, 2, 1, 42, (float("nan"), 0.0)), "malformed"),
    (Reply(SCHEMA, RUN, 3, 2, 1, 42, (0.0, float("inf"))), "malformed"),
    (Reply(SCHEMA, RUN, 3, 2, 1, 42, (0.0, 0.0), (0.0, 0.0), (1.0, float("nan"), 1.0)), "malformed"),
    (Command(SCHEMA, RUN, 3, -1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0)), "sender"),
    (Command(SCHEMA, RUN, 3, 1, (float("nan"), 0.0), 0, 0.0, (0, 0), (0.0, 0.0)), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, float("-inf"), (0, 0), (0.0, 0.0)), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), -1, 0.0, (0, 0), (0.0, 0.0)), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (-1, 0), (0.0, 0.0)), "malformed"),
    # a robot's own count of its step's robot-to-robot traffic: (kind, peer, copies, bytes)
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(0, 6, 1, 17)]), "sender"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(3, 2, 1, 17)]), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(0, 2, 3, 17)]), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(0, 2, 0, 17)]), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(0, 2, 1, -17)]), "malformed"),
    (Command(SCHEMA, RUN, 3, 1, (0.0, 0.0), 0, 0.0, (0, 0), (0.0, 0.0), None, [(0, 2, 1, 17)] * 9), "malformed"),
    (Measurement(SCHEMA, RUN, 3, 0.3, 1, (0.0, 0.0), -1.0), "malformed"),  # a negative range
    (Measurement(SCHEMA, RUN, 3, 0.3, 1, (0.0, 0.0), 1.0, [0, 9]), "sender"),  # in range of a robot 9
    (Measurement(SCHEMA, RUN, 3, 0.3, 1, (0.0, 0.0), 1.0, None, None, [(9, 2.0)]), "sender"),  # a link to robot 9
    (Measurement(SCHEMA, RUN, 3, 0.3, 1, (0.0, 0.0), 1.0, None, None, [(2, -2.0)]), "malformed"),  # negative length
    (Tick(SCHEMA, RUN, 3, 0.3, [(0.0, 0.0)] * 5, (0.0, 0.0), [0, 1, 2]), "malformed"),  # 5 positions for 6
    (Tick(SCHEMA, RUN, 3, 0.3, [(0.0, 0.0)] * 6, (0.0, 0.0), [0, -1]), "sender"),
    (End(SCHEMA, RUN, -1, "done", 1.0), "malformed"),
    (End(SCHEMA, RUN, 3, "over, trust me", 1.0), "malformed"),  # no reason a world gives
    # a digest's entries: the tick of another step, of another run, of another team; too many entries
    (Digest(SCHEMA, RUN, [DigestEntry(3, Tick(SCHEMA, RUN, 4, 0.3, [(0.0, 0.0)] * 6, (0.0, 0.0), [0]), [], [])]),
     "malformed"),
    (Digest(SCHEMA, RUN, [DigestEntry(3, Tick(SCHEMA, RUN + 1, 3, 0.3, [(0.0, 0.0)] * 6, (0.0, 0.0), [0]), [], [])]),
     "foreign"),
    (Digest(SCHEMA, RUN, [DigestEntry(3, Tick(SCHEMA, RUN, 3, 0.3, [(0.0, 0.0)] * 5, (0.0, 0.0), [0]), [], [])]),
     "malformed"),
    (Digest(SCHEMA, RUN, [DigestEntry(3, Tick(SCHEMA, RUN, 3, 0.3, [(0.0, 0.0)] * 6, (0.0, 0.0), [0, 7]), [], [])]),
     "sender"),
    (Digest(SCHEMA, RUN, [DigestEntry(3, None, [(1, 70)], [])] * 11), "size"),  # 10 entries for a team of 6
    # relayed ranges: a known step per robot of the team, sources in the team, no range the sender cannot hold
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [3] * 5, []), "malformed"),
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [3] * 6, [(6, 2, 0.0, 0.0, 1.0)]), "sender"),
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [3] * 6, [(0, 4, 0.0, 0.0, 1.0)]), "value"),  # a step after the message's
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [1] * 6, [(0, 2, 0.0, 0.0, 1.0)]), "value"),  # beyond what it holds
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [3, 3, 3, 3, 3, 4], []), "value"),  # holding ranges of a later step
    (RangeRequest(SCHEMA, RUN, 3, 1, 2, 42, [3] * 6, [(0, 2, 0.0, 0.0, -1.0)]), "malformed"),
    (RangeReply(SCHEMA, RUN, 3, 2, 1, 42, (0.0, 0.0), None, None, [3] * 6, [(0, 0, 0.0, 0.0, 1.0)]), "malformed"),
    (RangeReply(SCHEMA, RUN, 3, 2, 1, 42, (0.0, 0.0), None, None, [3] * 6, [(0, 2, float("nan"), 0.0, 1.0)]),
     "malformed"),
]


@pytest.mark.parametrize(("message", "reason"), BAD_VALUES, ids=[f"{m.kind}-{i}" for i, (m, _) in enumerate(BAD_VALUES)])
def test_impossible_values_are_rejected(message, reason: str) -> None:
    route = KEYS.parse(KEYS.data(*{
        "request": ("r2", "r1"), "reply": ("r1", "r2"), "command": ("world", "r1"), "measurement": ("r1", "world"),
        "tick": ("monitor", "world"), "end": ("all", "world"), "digest": ("monitor", "world"),
    }[message.kind], message.kind))
    with pytest.raises(Rejected) as raised:
        decode(encode(message), route, RUN, ROBOTS)
    assert raised.value.reason == reason


@given(st.sampled_from(["sender", "receiver"]), st.one_of(st.integers(-(2**40), -1), st.integers(ROBOTS, 2**40)))
def test_no_robot_id_outside_the_team_gets_through(field: str, robot: int) -> None:
    fields = {"sender": 1, "receiver": 2, field: robot}
    request = Request(SCHEMA, RUN, 3, fields["sender"], fields["receiver"], 42)
    route = KEYS.parse(KEYS.data(f"r{fields['receiver']}", f"r{fields['sender']}", "request"))
    with pytest.raises(Rejected) as raised:
        decode(encode(request), route, RUN, ROBOTS)
    assert raised.value.reason == "sender"


def test_neighbour_messages_are_compact() -> None:
    request = Request(SCHEMA, RUN, 123_456, 4, 5, 2**32 - 1)
    reply = Reply(SCHEMA, RUN, 123_456, 5, 4, 2**32 - 1, (12.345678901234, -3.21))
    assert len(encode(request)) <= 20
    assert len(encode(reply)) <= 42  # 2 floats of 9 bytes; absent belief fields cost 1 byte each


whole = st.integers(-int(BOUND), int(BOUND)).map(float)  # carried values are within BOUND


@given(st.lists(st.one_of(whole, finite, st.sampled_from([0.0, -0.0, 127.0, 128.0, -32.0, -33.0, 65535.0])),
                min_size=1, max_size=8), steps, robots, robots)
def test_carried_numbers_are_counted_exactly(values: list[float], step: int, sender: int, receiver: int) -> None:
    """A strategy's reply content travels compactly (whole numbers as msgpack integers) and
    robot_message_bytes counts its encoded size exactly; it decodes to the same floats."""
    assert len(msgspec.msgpack.encode(compact(values))) == 1 + int(number_bytes(values).sum())
    reply = CarryingReply(SCHEMA, RUN, step, sender, receiver, NONCE_BASE, (1.25, -2.5), carried=compact(values))
    wire = encode(reply)
    if any(value != 0 for value in values):
        assert len(wire) == int(robot_message_bytes("reply", step, sender, receiver, content=values))
    assert decode(wire, route_of(reply), RUN, ROBOTS).carried == tuple(values)


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
        newer = Request(SCHEMA, RUN, 4, 1, 2, 43)
        batch = [
            (KEYS.data("r2", "r1", "request"), encode(good), 1),
            (KEYS.data("r2", "r1", "request"), b"garbage", 1),
            (KEYS.data("r2", "r1", "request"), encode(Request(SCHEMA, 7, 3, 1, 2, 42)), 1),
            ("ringtrack/ffffffff/r2/r1/request", encode(good), 1),
            (KEYS.data("r2", "r1", "request"), encode(Stats(SCHEMA, RUN, "r1", False, [], [], {}, 0)), 1),
            (KEYS.data("r2", "r1", "request"), encode(newer), 2),  # r1's next life: from now on, life 1 is fenced
            (KEYS.data("r2", "r1", "request"), encode(good), 1),  # superseded
            (KEYS.data("r2", "r1", "request"), encode(good), 0),  # no life at all: unstamped
        ]
        accepted = participant.accept(batch)
    finally:
        loop.close()
    assert [event.message for event in accepted if isinstance(event, Delivery)] == [good, newer]
    assert dict(participant.counter.rejected) == {"malformed": 1, "foreign": 2, "route": 1, "superseded": 1,
                                                  "unstamped": 1}
    assert participant.counter.received_messages[("request", "r1", "r2")] == 2
    assert participant.lives == {"r1": 2}


def test_keys_keep_runs_apart() -> None:
    assert KEYS.prefix == "ringtrack/1234abcd"
    assert KEYS.parse("ringtrack/00000001/r2/r1/request") is None
    assert KEYS.parse(KEYS.data("r2", "r1", "request")).kind == "request"
    assert (robot_index("r12"), robot_index("world"), robot_index("r01"), robot_index("r-1")) == (12, None, None, None)
