"""Message schemas (msgspec structs, msgpack-encoded as compact tagged arrays) and their validation.

Every message starts ``[tag, schema, run, ...]``: ``tag`` names the kind, ``schema`` the version of
these definitions, ``run`` the 32-bit run id. Positions are metres as ``(x, y)``; ``time`` is
simulated seconds; ``step`` is the 1-based step. :func:`decode` rejects anything malformed,
of another schema or run, or claiming a sender its key does not carry, with a :class:`Rejected`
whose ``reason`` is counted by the receiver.
"""

from __future__ import annotations

import enum
from bisect import bisect_right
from functools import cache
from typing import Annotated, ClassVar

import msgspec
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.bus.faults import POLL_MESSAGES
from ringtrack.bus.keys import FUSION, MONITOR, WORLD, Route, robot_name

SCHEMA = 1

# Checked wire values: msgspec refuses NaN, infinities and out-of-range numbers while decoding
# ("malformed"), so no process ever computes with them. Robot ids are checked against the team in
# :func:`decode` ("sender").
BOUND = 1e9
Real = Annotated[float, msgspec.Meta(ge=-BOUND, le=BOUND)]
NonNegativeReal = Annotated[float, msgspec.Meta(ge=0.0, le=BOUND)]
Step = Annotated[int, msgspec.Meta(ge=1)]  # steps are 1-based
Count = Annotated[int, msgspec.Meta(ge=0)]
Nonce = Annotated[int, msgspec.Meta(ge=0, lt=2**32)]
Point = tuple[Real, Real]
Covariance = tuple[Real, Real, Real]  # (xx, xy, yy), m^2


class Message(msgspec.Struct, array_like=True, frozen=True, tag=True):
    schema: int
    run: int
    kind: ClassVar[str] = ""
    category: ClassVar[str] = ""  # "robot" (robot-to-robot), "world", "estimation" or "monitoring"


class Measurement(Message, tag=1, frozen=True):
    """World -> robot: the robot's exact position and a noisy range to the target (None: beyond
    r_s), with a limited communication range the live robots it can reach this step, and ``live``,
    the robots in the ring from this step on, when that changed (a robot came back) or is news to
    this robot (its first step after a restart); None otherwise. ``distances`` gives the length
    (metres) of its links to its live ring neighbours at the start of the step, as ``(robot,
    metres)`` pairs: what its radio's losses and energy depend on (:mod:`bus.radio`)."""

    step: Step
    time: NonNegativeReal
    robot: int
    position: Point
    range: NonNegativeReal | None
    in_range: list[int] | None = None
    live: list[int] | None = None
    distances: list[tuple[int, NonNegativeReal]] = []
    kind: ClassVar[str] = "measurement"
    category: ClassVar[str] = "world"


# What a robot-to-robot message of a lockstep step put on the bus, as the robot whose step it was
# counted it: ``(kind, peer, copies, payload bytes of each copy)``, ``kind`` an index into
# ROBOT_TRAFFIC_KINDS. A request or a push went from the robot to ``peer``; a reply came from
# ``peer``, one for each copy of the robot's request the peer received.
ROBOT_TRAFFIC_KINDS = ("request", "reply", "push")
RobotTraffic = tuple[Annotated[int, msgspec.Meta(ge=0, lt=len(ROBOT_TRAFFIC_KINDS))], int,
                     Annotated[int, msgspec.Meta(ge=1, le=2)], Count]


class Command(Message, tag=2, frozen=True):
    """Robot -> world: where to move this step, why it polled (a Trigger mask), and its view.

    ``guaranteed_offset`` is ``gV - theta`` (radians; None while the robot knows nothing of a
    neighbour, so its offset is no value of the ring) and ``ages`` the ages (steps) of its memory of
    its predecessor and successor, both as they were when it decided whether to poll; ``centre`` is
    the point it steers about (the known target or its estimate) with ``covariance`` when it
    estimates. ``robot_traffic`` is the robot's own count of the robot-to-robot messages its step
    put on the bus (:data:`RobotTraffic`: its requests and pushes, and the replies to its requests
    that came before it commanded: in lockstep, all of them); the world's lockstep digest hands it
    to the monitor, which then needs no copy of those messages. ``energy_j`` is the radio energy of
    the robot's robot-to-robot messages of the steps before this one (transmit, receive; joules,
    :mod:`bus.radio`; :meth:`bus.shim.LinkShim.energy_through`).
    """

    step: Step
    robot: int
    goal: Point
    trigger: Count
    guaranteed_offset: Real | None
    ages: tuple[Count, Count]
    centre: Point
    covariance: Covariance | None = None
    robot_traffic: Annotated[list[RobotTraffic], msgspec.Meta(max_length=8)] = []
    energy_j: tuple[NonNegativeReal, NonNegativeReal] | None = None
    kind: ClassVar[str] = "command"
    category: ClassVar[str] = "world"


class Request(Message, tag=3, frozen=True):
    """Robot -> ring neighbour: send me your state at the start of ``step``."""

    step: Step
    sender: int
    receiver: int
    nonce: Nonce
    kind: ClassVar[str] = "request"
    category: ClassVar[str] = "robot"


class Reply(Message, tag=4, frozen=True):
    """Ring neighbour -> robot: its position at the start of ``step`` (and belief when estimating),
    answering the request with ``nonce``."""

    step: Step
    sender: int
    receiver: int
    nonce: Nonce
    position: Point
    mean: Point | None = None
    covariance: Covariance | None = None
    kind: ClassVar[str] = "reply"
    category: ClassVar[str] = "robot"


class PushMeasurement(Measurement, tag=15, frozen=True):
    """A :class:`Measurement` that also names the ring neighbours that pushed their belief to this
    robot in the previous step (``pushed_by``, from their :class:`PushCommand`): in lockstep the
    robot waits for those pushes (bounded) before it fuses what it was told, so the result does not
    depend on whether a push or the world's message came first."""

    pushed_by: list[int] = []


class PushCommand(Command, tag=14, frozen=True):
    """A :class:`Command` of a strategy that pushes: also names the neighbours the robot pushed its
    belief to in this step (``pushed``)."""

    pushed: list[int] = []


class BeliefRequest(Request, tag=12, frozen=True):
    """A :class:`Request` that carries the requester's belief, the target estimate ``mean``
    (metres) and ``covariance`` (m^2) as it was when it decided to poll; the polled neighbour fuses
    it in its next step."""

    mean: Point
    covariance: Covariance


class CarryingReply(Reply, tag=13, frozen=True):
    """A :class:`Reply` that also carries what the strategy puts in its replies (``carried``:
    :meth:`agents.strategy.Strategy.reply_content`). A reply whose content is all zeros is sent as
    a plain :class:`Reply` and read back as zeros (:func:`carries_content`)."""

    carried: Annotated[tuple[Real, ...], msgspec.Meta(max_length=32)] = ()


MAX_RELAYED = 2048  # ranges one RangeRequest or RangeReply carries at most (the sender keeps the newest)
RANGE_ENTRY_MAX_BYTES = 38  # the most one relayed range takes: 1 + 5 + 5 + 3 * 9
# A relayed range: (source robot, step, x, y, range), the position (metres) the source robot took
# its range from at that step and the range (metres; None: beyond the sensing range).
RelayedRange = tuple[int, Step, Real, Real, NonNegativeReal | None]
# Per robot of the team (at most 100 000): the last step of its ranges the sender holds.
Known = Annotated[list[Count], msgspec.Meta(max_length=100_000)]
Relayed = Annotated[list[RelayedRange], msgspec.Meta(max_length=MAX_RELAYED)]


class RangeRequest(Request, tag=18, frozen=True):
    """A :class:`Request` of the ``relay`` strategy (:mod:`agents.relay`): ``known[j]`` is the last
    step of robot j's ranges the requester held as the step began (it holds them all up to it, bar
    those too old to keep), ``ranges`` those of them the receiver may lack, as
    :data:`RelayedRange` entries (docs/algorithms.md section 20)."""

    known: Known
    ranges: Relayed


class RangeReply(Reply, tag=19, frozen=True):
    """A :class:`Reply` of the ``relay`` strategy: the replier's ``known`` and the ``ranges`` the
    requester lacks (as its request said), as :class:`RangeRequest`; no belief (it is not fused)."""

    known: Known = []
    ranges: Relayed = []


class Push(Message, tag=11, frozen=True):
    """Ring neighbour -> robot, unasked: the sender's belief (``mean`` metres, ``covariance`` m^2)
    at ``step`` (after its own update and what it was told, before its poll), sent when it moved
    enough since the belief it last told (:meth:`agents.strategy.Strategy.wants_push`)."""

    step: Step
    sender: int
    receiver: int
    mean: Point
    covariance: Covariance
    kind: ClassVar[str] = "push"
    category: ClassVar[str] = "robot"


class Tick(Message, tag=5, frozen=True):
    """World -> monitor: the true state at the start of ``step`` (never sent to robots); in lockstep,
    unless the monitor audits, carried in the step's :class:`DigestEntry` instead of sent alone."""

    step: Step
    time: NonNegativeReal
    positions: list[Point]
    target: Point
    live: list[int]
    kind: ClassVar[str] = "tick"
    category: ClassVar[str] = "monitoring"


class EndReason(enum.StrEnum):
    """Why a run ended: the world's :class:`End` and the run log's end record carry its value."""

    DONE = "done"  # every step asked for was run
    CONVERGED = "converged"  # the world ended the run at convergence
    RING_EMPTY = "every robot left the ring"  # they all crashed or quit: a failed run
    SIGINT = "interrupted (SIGINT)"
    SIGTERM = "interrupted (SIGTERM)"
    PARENT_EXITED = "interrupted (parent exited)"  # the process that started the world went away
    MONITOR_STOPPED = "monitor stopped"  # the log only: the monitor stopped before the world's End
    MONITOR_LOST = "the monitor went away"  # the world ended the run: nobody keeps its log and books

    @classmethod
    def interrupted_by(cls, cause: str) -> EndReason:
        """The reason of a run stopped by ``cause`` ("SIGINT", "SIGTERM", "parent exited")."""
        return cls(f"interrupted ({cause})")

    @property
    def interrupted(self) -> bool:
        """Stopped from outside (a signal, or the parent's end) rather than by the run itself."""
        return self in (EndReason.SIGINT, EndReason.SIGTERM, EndReason.PARENT_EXITED)

    def text(self, step: int | None = None) -> str:
        """Why the run ended, in words (``step``: the last step run, named where it matters)."""
        if self is EndReason.RING_EMPTY and step is not None:
            return f"{self.value} by step {step}"
        return {EndReason.SIGINT: "interrupted by the user (Ctrl-C)", EndReason.SIGTERM: "terminated (SIGTERM)",
                EndReason.PARENT_EXITED: "stopped (its parent process went away)"}.get(self, self.value)


class End(Message, tag=6, frozen=True):
    """World -> everyone: the run is over after ``step`` steps, and why."""

    step: Count  # 0: stopped before its first step
    reason: EndReason
    wall_s: NonNegativeReal
    kind: ClassVar[str] = "end"
    category: ClassVar[str] = "world"


Traffic = tuple[str, str, str, int, int]  # (kind, source, destination, messages, bytes)


class Stats(Message, tag=7, frozen=True):
    """Any process -> monitor: what it has sent and received so far, by kind and link, payloads it
    rejected by reason, what the fault layer did to its robot-to-robot messages, and protocol
    counters (``notes``: e.g. replies ignored for a wrong nonce, probes of unreachable neighbours);
    a robot also reports the radio energy of its robot-to-robot traffic (joules)."""

    name: str
    final: bool
    sent: list[Traffic]
    received: list[Traffic]
    rejected: dict[str, Count]
    rss_kib: Count
    faults: dict[str, int] = {}
    notes: dict[str, int] = {}
    energy_j: tuple[NonNegativeReal, NonNegativeReal] | None = None  # robots: radio energy (transmit, receive)
    kind: ClassVar[str] = "stats"
    category: ClassVar[str] = "monitoring"


class FaultNotice(Message, tag=10, frozen=True):
    """Robot -> monitor: the fault layer ``dropped`` (``reason``: drop, outage, range, gone, radio),
    ``duplicated`` or ``delayed`` (by ``delay_s``) the ``subject`` message ``sender -> receiver``."""

    step: Step
    subject: str
    sender: int
    receiver: int
    what: str
    reason: str
    delay_s: NonNegativeReal
    kind: ClassVar[str] = "fault"
    category: ClassVar[str] = "monitoring"


class DigestEntry(msgspec.Struct, array_like=True, frozen=True):
    """One step of a :class:`Digest`: the step's ``tick``, ``measurements`` as ``(robot, payload
    bytes)`` of those the world published for ``step`` and ``commands`` every command it received,
    with its payload bytes. A step whose commands outnumber the team (forged or repeated ones) takes
    further entries of the team's size, with no tick and no measurements."""

    step: Step
    tick: Tick | None
    measurements: list[tuple[int, Count]]
    commands: list[tuple[Command | PushCommand, Count]]  # a PushCommand for strategies that push


class Digest(Message, tag=17, frozen=True):
    """World -> monitor in lockstep unless the monitor audits every message itself: the world's own
    account of its links in the steps since its previous digest (oldest first), so the monitor need
    not receive a copy of every measurement and command, nor a tick of its own each step. At most
    :func:`digest_entries` entries. ``replayed``: steps the world kept while its monitor was away,
    sent to the monitor that came back (:mod:`world.backlog`)."""

    entries: list[DigestEntry]
    replayed: bool = False
    kind: ClassVar[str] = "digest"
    category: ClassVar[str] = "monitoring"


DIGEST_ROBOT_ENTRIES = 64  # a digest carries at most this many robots' worth of step entries


def digest_entries(robots: int) -> int:
    """How many entries a :class:`Digest` may carry in a team of ``robots``: ten steps of six robots,
    one step from 33 robots on (a step of 64 robots takes about 10 kB)."""
    return max(1, DIGEST_ROBOT_ENTRIES // robots)


class RangeReport(Message, tag=8, frozen=True):
    """Robot -> fusion centre (centralized estimation): its position and measured range (None:
    beyond the sensing range) at the start of ``step``, and the ring from this step on when the
    world announced a change (:attr:`Measurement.live`)."""

    step: Step
    robot: int
    position: Point
    range: NonNegativeReal | None
    live: list[int] | None = None
    kind: ClassVar[str] = "range"
    category: ClassVar[str] = "estimation"


class Estimate(Message, tag=9, frozen=True):
    """Fusion centre -> every robot: the centralized estimate of the target after ``step``'s ranges."""

    step: Step
    mean: Point
    covariance: Covariance
    kind: ClassVar[str] = "estimate"
    category: ClassVar[str] = "estimation"


KINDS: dict[str, type[Message]] = {
    cls.kind: cls
    for cls in (Measurement, Command, Request, Reply, Push, Tick, End, Stats, RangeReport, Estimate, FaultNotice,
                Digest)
}
AnyMessage = (Measurement | PushMeasurement | Command | PushCommand | Request | BeliefRequest | RangeRequest | Reply
              | CarryingReply | RangeReply | Push | Tick | End | Stats | RangeReport | Estimate | FaultNotice | Digest)
RobotMessage = Request | Reply | Push  # robot-to-robot: through the fault layer

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(AnyMessage)


class Rejected(ValueError):
    """A received payload was dropped; ``reason`` is one of :data:`REJECT_REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


# "value": well formed and from a team member, but impossible for this run (e.g. a goal off the
# boundary); counted by the receiver that can tell.
# "size": longer than its kind can be (trailing fields, padding): refused before or after decoding.
# "window": stamped with a step too far ahead of the receiver's to be genuine (a forged step 2^64-1):
# dropped at the door by the receiver's own check (:attr:`bus.participant.Participant.window`).
# "superseded": sent by an older life of a robot id than one the receiver has seen (:mod:`bus.lives`);
# "unstamped": claiming a robot id whose lives the receiver knows, but stamped with no life at all.
REJECT_REASONS = ("malformed", "schema", "foreign", "route", "sender", "value", "size", "window", "superseded",
                  "unstamped")


def size_limit(kind: str, robots: int) -> int:
    """The most bytes a payload of ``kind`` can take in a team of ``robots``: generous bounds on the
    fields (a list of robot ids or positions: at most 64 bytes per robot; statistics: a traffic row
    per link) refused before decoding, so a 1 MiB payload costs nothing to drop."""
    if kind == "digest":  # a command (<= 128 bytes), a measurement row and a tick row per robot and entry
        return 1024 + 224 * robots * digest_entries(robots)
    per_robot = {"stats": 1024}.get(kind, 64)
    relayed = MAX_RELAYED * RANGE_ENTRY_MAX_BYTES + 5 * robots if kind in ("request", "reply") else 0  # relay
    return 1024 + per_robot * robots + relayed


def encode(message: Message) -> bytes:
    return _encoder.encode(message)


def decode(payload: bytes, route: Route | None, run: int, robots: int) -> AnyMessage:
    """Decode and validate ``payload`` received on ``route`` in run ``run`` of ``robots`` robots.

    Raises :class:`Rejected` for a payload longer than its kind can be ("size"), bytes that are not
    a message ("malformed"), another schema
    version ("schema"), another run ("foreign"), a kind that does not match the key ("route"), or
    a sender/receiver that is not the one its key names or not a robot of this team ("sender").
    """
    if route is not None and len(payload) > size_limit(route.kind, robots):
        raise Rejected("size", f"{len(payload)} bytes on {route}, more than a {route.kind} can be")
    try:
        message = _decoder.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError) as error:
        raise Rejected("malformed", str(error)) from None
    # Decoding skips trailing fields: a payload longer than the message re-encoded (every float in
    # 9 bytes; compact senders send whole numbers shorter) carries some.
    if len(payload) > len(encode(message)):
        raise Rejected("size", f"{len(payload)} bytes for a {message.kind} of {len(encode(message))}")
    if message.schema != SCHEMA:
        raise Rejected("schema", f"schema {message.schema}, expected {SCHEMA}")
    if message.run != run or route is None:
        raise Rejected("foreign", f"run {message.run:#x} on {route}")
    if route.kind != message.kind:
        raise Rejected("route", f"{message.kind} sent as {route.kind}")
    named = robot_ids(message)
    if named and not (min(named) >= 0 and max(named) < robots):
        robot = next(robot for robot in named if not 0 <= robot < robots)
        raise Rejected("sender", f"{message.kind} names robot {robot}, not one of a team of {robots}")
    if isinstance(message, Digest):
        _check_digest(message, run, robots)
    if isinstance(message, Tick):
        _check_tick(message, robots)
    if isinstance(message, (RangeRequest, RangeReply)):
        _check_relayed(message, robots)
    source, destination = endpoints(message)
    if source != route.source or destination not in (route.destination, None):
        raise Rejected("sender", f"{message.kind} from {source} to {destination} on {route}")
    return message


def _check_tick(tick: Tick, robots: int) -> None:
    if len(tick.positions) != robots:
        raise Rejected("malformed", f"tick with {len(tick.positions)} positions for a team of {robots}")


def _check_relayed(message: RangeRequest | RangeReply, robots: int) -> None:
    """What :func:`decode` checks of relayed ranges beyond their fields: a known step per robot, none
    after the message's step, and no range of a step after it nor beyond what the sender says it holds."""
    if len(message.known) != robots:
        raise Rejected("malformed", f"{message.kind} with {len(message.known)} known steps for a team of {robots}")
    if any(step > message.step for step in message.known) or \
            any(step > message.step or step > message.known[source] for source, step, *_ in message.ranges):
        raise Rejected("value", f"{message.kind} of step {message.step} relaying a range it cannot hold")


def _check_digest(digest: Digest, run: int, robots: int) -> None:
    """What :func:`decode` checks of a digest beyond its own fields: the ticks and commands it carries."""
    if len(digest.entries) > digest_entries(robots):
        raise Rejected("size", f"a digest of {len(digest.entries)} entries, more than {digest_entries(robots)}")
    for entry in digest.entries:
        carried = [command for command, _ in entry.commands] + ([] if entry.tick is None else [entry.tick])
        if any((message.schema, message.run) != (SCHEMA, run) for message in carried):
            raise Rejected("foreign", "a digest carrying a message of another schema or run")
        if entry.tick is not None:
            if entry.tick.step != entry.step:
                raise Rejected("malformed", f"a digest entry of step {entry.step} with the tick of {entry.tick.step}")
            _check_tick(entry.tick, robots)


def peek(payload: bytes) -> AnyMessage:
    """Decode ``payload`` without checking it against a run or a team (for an observer that knows
    neither); raises :class:`Rejected` ("malformed") for bytes that are not a message."""
    try:
        return _decoder.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError) as error:
        raise Rejected("malformed", str(error)) from None


def robot_ids(message: Message) -> list[int]:
    """Every robot index a message names (all must belong to the team)."""
    if isinstance(message, (RangeRequest, RangeReply)):
        return [message.sender, message.receiver, *(entry[0] for entry in message.ranges)]
    if isinstance(message, (Request, Reply, Push, FaultNotice)):
        return [message.sender, message.receiver]
    if isinstance(message, Measurement):
        return [message.robot, *(message.in_range or ()), *(message.live or ()),
                *(robot for robot, _ in message.distances), *getattr(message, "pushed_by", ())]
    if isinstance(message, Command):
        return [message.robot, *getattr(message, "pushed", ()), *(row[1] for row in message.robot_traffic)]
    if isinstance(message, RangeReport):
        return [message.robot, *(message.live or ())]
    if isinstance(message, Tick):
        return list(message.live)
    if isinstance(message, Digest):
        return [robot for entry in message.entries for robot in (
            *(robot for robot, _ in entry.measurements), *(() if entry.tick is None else entry.tick.live),
            *(robot for command, _ in entry.commands for robot in robot_ids(command)))]
    return []


def endpoints(message: Message) -> tuple[str, str | None]:
    """``(source, destination)`` participant names a message claims (destination None: any)."""
    if isinstance(message, (Request, Reply, Push)):
        return robot_name(message.sender), robot_name(message.receiver)
    if isinstance(message, Measurement):
        return WORLD, robot_name(message.robot)
    if isinstance(message, Command):
        return robot_name(message.robot), WORLD
    if isinstance(message, Stats):
        return message.name, MONITOR
    if isinstance(message, Digest):
        return WORLD, MONITOR
    if isinstance(message, RangeReport):
        return robot_name(message.robot), FUSION
    if isinstance(message, Estimate):
        return FUSION, None
    if isinstance(message, FaultNotice):  # a request's fate is decided by its sender, a reply's or push's on arrival
        return robot_name(message.sender if message.subject == "request" else message.receiver), MONITOR
    return WORLD, None


NONCE_BASE = 2**31  # nonces and run ids are drawn from [2^31, 2^32): always 5 bytes on the wire


_UINT_LIMITS = np.array([128, 256, 65536])  # msgpack: positive fixint, uint 8, uint 16, uint 32
_UINT_SIZES = np.array([1, 2, 3, 5], dtype=np.int64)
_UINT_LIMIT_LIST = _UINT_LIMITS.tolist()


def uint_bytes(value: ArrayLike) -> NDArray[np.int64]:
    """Bytes msgpack takes for non-negative integers below 2^32 (1, 2, 3 or 5). One Python int (a
    step number) is placed by ``bisect`` rather than numpy's ``searchsorted``: the same size without
    numpy's cost per call."""
    if isinstance(value, int):
        return _UINT_SIZES[bisect_right(_UINT_LIMIT_LIST, value)]
    sizes: NDArray[np.int64] = _UINT_SIZES[np.searchsorted(_UINT_LIMITS, value, side="right")]
    return sizes


@cache
def _robot_message_base(kind: str, belief: bool, carried: int = 0) -> int:
    """Encoded bytes of a robot-to-robot message of step 1 from robot 0 to robot 0."""
    mean, covariance = (0.0, 0.0), (0.0, 0.0, 0.0)
    if kind == "push":
        return len(encode(Push(SCHEMA, NONCE_BASE, 1, 0, 0, mean, covariance)))
    if kind == "request":
        if belief:
            return len(encode(BeliefRequest(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE, mean, covariance)))
        return len(encode(Request(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE)))
    extra = (mean, covariance) if belief else (None, None)
    if carried:
        return len(encode(CarryingReply(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE, (0.0, 0.0), mean=extra[0],
                                        covariance=extra[1], carried=(0.0,) * carried)))
    return len(encode(Reply(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE, (0.0, 0.0), *extra)))


def robot_message_bytes(kind: str, step: ArrayLike, sender: ArrayLike, receiver: ArrayLike,
                        belief: bool = False, content: ArrayLike | None = None) -> NDArray[np.int64]:
    """The exact encoded size of requests, replies or pushes (``kind``; a reply with a ``belief``
    carries a mean and covariance, a request with one is a :class:`BeliefRequest`, a reply with
    ``content``, the strategy's floats on the last axis, is a :class:`CarryingReply` where
    :func:`carries_content`, its whole numbers sent as integers, see :func:`compact`) of ``step``
    from ``sender`` to ``receiver``, broadcast over arrays: the size of the step-1, robot-0 message
    plus the extra bytes the larger integers take (other floats are always 9 bytes, nonces and run
    ids 5)."""
    extra = uint_bytes(step) + uint_bytes(sender) + uint_bytes(receiver) - 3
    plain = _robot_message_base(kind, belief) + extra
    if content is None or kind != "reply":
        return plain
    content = np.asarray(content, dtype=float)
    fields = content.shape[-1]
    carrying = _robot_message_base(kind, belief, fields) - 9 * fields + extra + number_bytes(content).sum(axis=-1)
    return np.where(carries_content(content), carrying, plain)


def carries_content(content: ArrayLike) -> NDArray[np.bool_]:
    """Whether a reply whose strategy content is ``content`` (last axis: the fields) is sent as a
    :class:`CarryingReply`: only content with a non-zero field says more than a plain reply."""
    return np.any(np.asarray(content) != 0, axis=-1)


WHOLE_LIMIT = 2**31  # whole numbers below this magnitude travel as msgpack integers (compact)


def compact(values: ArrayLike) -> tuple[float | int, ...]:
    """``values`` as a message carries them: whole numbers of magnitude below :data:`WHOLE_LIMIT`
    as integers (1 to 5 bytes; a float field decodes them as floats, and the sign of a zero is
    not kept), every other value as a 9-byte float (:func:`number_bytes`)."""
    return tuple(int(value) if value.is_integer() and abs(value) < WHOLE_LIMIT else value
                 for value in np.asarray(values, dtype=float).ravel().tolist())


def number_bytes(values: ArrayLike) -> NDArray[np.int64]:
    """Encoded bytes of each of ``values`` as :func:`compact` sends it: msgpack's smallest integer
    (1 byte for -32..127, 2 for -128..255, 3 for -32768..65535, else 5) or 9 for a float."""
    values = np.asarray(values, dtype=float)
    whole = np.isfinite(values) & (values == np.round(values)) & (np.abs(values) < WHOLE_LIMIT)
    number = np.where(whole, values, 0.0)
    integer = np.select([(number >= -32) & (number <= 127), (number >= -128) & (number <= 255),
                         (number >= -32768) & (number <= 65535)], [1, 2, 3], 5)
    return np.where(whole, integer, 9).astype(np.int64)


def poll_bytes(with_belief: bool) -> int:
    """Payload bytes of one poll that meets no fault (:data:`bus.faults.POLL_MESSAGES`: a request
    and a reply per neighbour) with typical field sizes (a step in the thousands, robots 1 and 2),
    for counts the engine only infers (:func:`robot_message_bytes`)."""
    request = int(robot_message_bytes("request", 1000, 1, 2))
    reply = int(robot_message_bytes("reply", 1000, 2, 1, with_belief))
    return POLL_MESSAGES // 2 * (request + reply)


@cache
def _relay_message_base(kind: str) -> int:
    """Encoded bytes of a relay request or reply of step 1 from robot 0 to robot 0, known and ranges empty."""
    if kind == "request":
        return len(encode(RangeRequest(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE, [], [])))
    return len(encode(RangeReply(SCHEMA, NONCE_BASE, 1, 0, 0, NONCE_BASE, (0.0, 0.0))))


def array_header_bytes(length: ArrayLike) -> NDArray[np.int64]:
    """Bytes of msgpack's header of an array of ``length`` items (1 up to 15, 3 up to 65535, else 5)."""
    length = np.asarray(length)
    return np.where(length <= 15, 1, np.where(length <= 65535, 3, 5)).astype(np.int64)


def relayed_range_bytes(source: ArrayLike, step: ArrayLike, measured: ArrayLike) -> NDArray[np.int64]:
    """Encoded bytes of one :data:`RelayedRange`: robot ``source``'s range of ``step``, a float when
    ``measured`` (9 bytes), else None (1 byte), the position's two floats (18 bytes)."""
    return (1 + uint_bytes(source) + uint_bytes(step) + 18 + np.where(measured, 9, 1)).astype(np.int64)


def known_steps_bytes(known: ArrayLike) -> NDArray[np.int64]:
    """Bytes of the ``known`` list a relay message carries (the last step of each robot's ranges its
    sender holds, one per robot on the last axis) beyond those of an empty list."""
    known = np.asarray(known)
    return array_header_bytes(known.shape[-1]) - 1 + uint_bytes(known).sum(axis=-1)


def relay_message_bytes(kind: str, step: ArrayLike, sender: ArrayLike, receiver: ArrayLike, known_bytes: ArrayLike,
                        count: ArrayLike, entry_bytes: ArrayLike) -> NDArray[np.int64]:
    """The exact encoded size of :class:`RangeRequest` (``kind`` "request") or :class:`RangeReply`
    ("reply") messages of ``step`` from ``sender`` to ``receiver``, carrying a known list of
    ``known_bytes`` (:func:`known_steps_bytes`) and ``count`` ranges of ``entry_bytes`` bytes in all
    (:func:`relayed_range_bytes`), broadcast over arrays. Nonces and run ids take 5 bytes."""
    extra = uint_bytes(step) + uint_bytes(sender) + uint_bytes(receiver) - 3
    ranges_bytes = array_header_bytes(count) - 1 + np.asarray(entry_bytes, dtype=np.int64)
    return (_relay_message_base(kind) + extra + np.asarray(known_bytes, dtype=np.int64) + ranges_bytes).astype(np.int64)
