"""Ranges relayed around the ring: every robot's filter takes every robot's ranges, late.

A range is a scalar and the position it was taken from: a message can carry the ranges its sender
holds and its receiver does not. With the ring's own requests and replies carrying them (no message
of their own), each robot's knowledge of each other robot's ranges is a prefix of steps
(:attr:`RangeRelay.known`) that grows each time a message of a neighbour who knew more reaches it,
so a range travels one hop per message. Each filter takes each range exactly once (no double
counting, so no covariance intersection), at the first step after it arrived, as a measurement of
the target now:

* the target has moved since the range was taken: the robot moves the range's origin by its own
  estimate of that displacement, ``age`` times the drift of its mean over the last
  ``VELOCITY_WINDOW_S`` seconds (:class:`Drift`), and
* what that estimate misses widens the range's variance by the random walk's ``age q``
  (:func:`late_variance`).

:class:`RangeRelay` is the engine's state for a batch of rings (with the exact size of every message,
:meth:`RangeRelay.message_bytes`); :class:`RobotRanges` is one robot process's, which sends and
receives the ranges in :class:`bus.messages.RangeRequest` and :class:`bus.messages.RangeReply`
(docs/algorithms.md section 20).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ringtrack.bus.messages import MAX_RELAYED, known_steps_bytes, relay_message_bytes, uint_bytes
from ringtrack.world.elementwise import Values
from ringtrack.world.geometry import FloatArray
from ringtrack.world.ring import predecessor_values, successor_values

VELOCITY_WINDOW_S = 5.0  # s: a robot's velocity estimate is its mean's drift over this long


def late_variance(range_sigma: float, process_noise: float, age: NDArray[np.int64]) -> FloatArray:
    """The variance (m^2) of a range taken ``age`` steps ago as a measurement of the target now: the
    sensor's ``range_sigma^2`` (m^2) plus the random walk's ``age q`` (``q`` m^2 per step) along the
    line of sight. The motion since is treated as noise of that range alone (it is shared by every
    late range and the prior): exact for a range of this step, an approximation for older ones."""
    return np.asarray(range_sigma**2 + process_noise * age, dtype=float)


def bearing_sd(own_position: FloatArray, centre: FloatArray, covariance: FloatArray) -> Values:
    """The standard deviation (radians) of the bearing from ``centre`` (metres, ``S + (2,)``) to
    ``own_position`` (metres) that the covariance of the centre (m^2, ``S + (2, 2)``) implies, to
    first order: ``sqrt(d_perp^T P d_perp) / |d|^2`` with ``d`` the offset from the centre and
    ``d_perp`` it turned a quarter counter-clockwise. Plain arithmetic on the components, so a
    robot's scalars and a batch's arrays give the same bits."""
    dx = own_position[..., 0] - centre[..., 0]
    dy = own_position[..., 1] - centre[..., 1]
    across = (covariance[..., 0, 0] * dy * dy - 2.0 * covariance[..., 0, 1] * dx * dy
              + covariance[..., 1, 1] * dx * dx)
    return np.sqrt(across) / (dx * dx + dy * dy)


def ranges_wanted(covariance: FloatArray, steady_variance: float, terr_ratio: float) -> Values:
    """Whether an estimate's covariance (m^2, ``S + (2, 2)``) is wider than ``terr_ratio^2`` times
    the ``2 steady_variance`` (m^2, both axes) of a filter taking every robot's range every step:
    its expected squared error exceeds what a Terr ``terr_ratio`` times that filter's allows. Never
    for a target with no steady state (``steady_variance`` 0: a stationary target's)."""
    trace = covariance[..., 0, 0] + covariance[..., 1, 1]
    return (trace > terr_ratio * terr_ratio * 2.0 * steady_variance) & (steady_variance > 0.0)


class Drift:
    """Filters' estimates of the target's velocity (metres per step): the drift of their means over
    the last ``window`` steps (fewer at the start; zero at the first)."""

    def __init__(self, window: int) -> None:
        self.window = max(1, window)
        self.means: list[FloatArray] = []  # the means at the last window + 1 steps

    def velocities(self, means: FloatArray) -> FloatArray:
        """The velocities (B, 2) given this step's ``means`` (B, 2), metres, before their update."""
        self.means.append(means)
        if len(self.means) > self.window + 1:
            self.means.pop(0)
        return (means - self.means[0]) / max(1, len(self.means) - 1)


class RangeRelay:
    """Which ranges each robot of a batch of rings holds, and the ranges themselves.

    ``known[t, r, j]`` is the last step of robot j's ranges that robot r of trial t holds (it holds
    all steps up to it; 0: none), ``applied[t, r, j]`` the last its filter took. Ranges (metres, NaN:
    none) and the positions they were taken from (metres) are kept for ``steps`` steps, and each
    robot's mean (metres) for the last ``window`` steps (:class:`Drift`).
    """

    def __init__(self, trials: int, robots: int, steps: int, window: int) -> None:
        self.known = np.zeros((trials, robots, robots), dtype=np.int64)
        self.applied = np.zeros((trials, robots, robots), dtype=np.int64)
        self.ranges = np.full((steps + 1, trials, robots), np.nan)
        self.positions = np.zeros((steps + 1, trials, robots, 2))
        self.drift = Drift(window)  # of the robots' means (T*N, 2)
        self._own = np.eye(robots, dtype=bool)[None]
        # told[t, r, s, j]: the last step of robot j's ranges robot r heard its predecessor (s = 0) or
        # successor (s = 1) hold, from their messages (what r's requests need not carry again)
        self.told = np.zeros((trials, robots, 2, robots), dtype=np.int64)
        self.measured = np.zeros((steps + 1, trials, robots), dtype=np.int64)  # ranges measured up to each step
        # indices of every (trial, robot, source) and, per side, each robot's neighbour there
        self._trial = np.arange(trials)[:, None, None]
        self._source = np.arange(robots)[None, None, :]
        robot = np.arange(robots)
        self._neighbours = ((robot - 1) % robots, (robot + 1) % robots)
        self._entry_base = 19 + uint_bytes(self._source)  # bytes of a relayed range bar its step's and range's

    def take(
        self, step: int, means: FloatArray, range_sigma: float, process_noise: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The ranges each robot holds and its filter has not taken, now marked taken, as measurements
        of the target at ``step`` by filters whose means (T*N, 2) are ``means``: origins (T*N, M, 2)
        moved by the estimated displacement since each was taken, ranges (T*N, M) (NaN pads rows to
        the longest, M) and variances (T*N, M) (:func:`late_variance`)."""
        trials, robots, _ = self.known.shape
        velocity = self.drift.velocities(means)
        waiting = self.known - self.applied
        longest = int(waiting.max(initial=0))
        rows = trials * robots
        if longest == 0:
            return np.zeros((rows, 0, 2)), np.zeros((rows, 0)), np.zeros((rows, 0))
        offset = np.arange(1, longest + 1)
        valid = offset <= waiting[..., None]
        taken = np.where(valid, self.applied[..., None] + offset, 0)  # (T, N, N, M'): steps of each source
        trial = np.arange(trials)[:, None, None, None]
        source = np.arange(robots)[None, None, :, None]
        ranges = np.where(valid, self.ranges[taken, trial, source], np.nan).reshape(rows, -1)
        ages = (step - taken).reshape(rows, -1)
        origins = self.positions[taken, trial, source].reshape(rows, -1, 2) + velocity[:, None, :] * ages[..., None]
        self.applied = self.known.copy()
        return origins, ranges, late_variance(range_sigma, process_noise, ages)

    def record(self, step: int, positions: FloatArray, ranges: FloatArray) -> None:
        """Every robot's own range of ``step`` (T, N), metres, from ``positions`` (T, N, 2): it holds
        and takes it."""
        self.ranges[step], self.positions[step] = ranges, positions
        self.measured[step] = self.measured[step - 1] + np.isfinite(ranges)
        self.known = np.where(self._own, step, self.known)
        self.applied = np.where(self._own, step, self.applied)

    def hand_over(self, from_predecessor: NDArray[np.bool_], from_successor: NDArray[np.bool_]) -> None:
        """A message of this step reached each robot (T, N) from its predecessor, its successor: each
        carried every range its sender held as the step began (its own range of the step included)."""
        before = self.known
        heard = np.maximum(
            np.where(from_predecessor[..., None], predecessor_values(before, axis=1), 0),
            np.where(from_successor[..., None], successor_values(before, axis=1), 0),
        )
        self.known = np.maximum(before, heard)
        for side, came, values in ((0, from_predecessor, predecessor_values), (1, from_successor, successor_values)):
            self.told[:, :, side] = np.where(came[..., None], np.maximum(self.told[:, :, side], values(before, axis=1)),
                                             self.told[:, :, side])

    def message_bytes(self, step: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The exact encoded sizes (bytes, (T, N, 2) each) of every robot's relay request of ``step``
        to its (predecessor, successor) and of the reply each of them would send it
        (:func:`bus.messages.relay_message_bytes`), as the robot processes build them (call after
        :meth:`record`): a request carries the ranges ``(told, known]`` of each source (none of its
        receiver's own), a reply those of ``(requester's known, replier's known]``."""
        known = self.known
        robot = self._source[0, 0]
        known_bytes = known_steps_bytes(known)  # (T, N): each robot's known list, in its requests and replies
        requests = np.empty(known.shape[:2] + (2,), dtype=np.int64)
        replies = np.empty(known.shape[:2] + (2,), dtype=np.int64)
        for side, neighbour in enumerate(self._neighbours):
            receiver_is = neighbour[None, :, None] == self._source  # (1, N, N): source j is the receiver
            requests[..., side] = self._bytes("request", step, robot, neighbour, known, known_bytes,
                                              self.told[:, :, side], receiver_is)
            replies[..., side] = self._bytes("reply", step, neighbour, robot, known[:, neighbour],
                                             known_bytes[:, neighbour], known, self._own)
        return requests, replies

    def _bytes(self, kind: str, step: int, sender: NDArray[np.int64], receiver: NDArray[np.int64],
               known: NDArray[np.int64], known_bytes: NDArray[np.int64], base: NDArray[np.int64],
               skipped: NDArray[np.bool_]) -> NDArray[np.int64]:
        """Sizes (T, N) of ``kind`` messages from ``sender`` to ``receiver`` (N,) carrying the sender's
        ``known`` (T, N, N), a list of ``known_bytes`` (T, N), and the ranges ``(base, known]`` of
        each source not ``skipped``."""
        low = np.minimum(base, known)
        high = np.where(skipped, low, known)
        count = high - low
        measured = self.measured[high, self._trial, self._source] - self.measured[low, self._trial, self._source]
        entry = np.add.reduce(count * self._entry_base + _step_bytes(high) - _step_bytes(low) + 9 * measured
                              + (count - measured), axis=-1)
        return relay_message_bytes(kind, step, sender[None], receiver[None], known_bytes,
                                   np.add.reduce(count, axis=-1), entry)


def _step_bytes(steps: NDArray[np.int64]) -> NDArray[np.int64]:
    """``sum over i in 1..steps of uint_bytes(i)``: the bytes msgpack takes for the steps 1 to ``steps``."""
    return steps + np.maximum(0, steps - 127) + np.maximum(0, steps - 255) + 2 * np.maximum(0, steps - 65535)


RELAY_KEPT_STEPS = 2000  # a robot process keeps the ranges of this many last steps (older ones are past use)
SNAPSHOT_STEPS = 16  # ... and what it held as each of the last steps began (as agents.node.KEPT_STEPS)
Relayed = tuple[int, int, float, float, float | None]  # (source, step, x, y, range): bus.messages.RelayedRange


class RobotRanges:
    """What one robot process holds of the team's ranges, the ``relay`` strategy's state of
    :class:`RangeRelay` for a single robot (docs/algorithms.md section 20).

    ``known[j]`` is the last step of robot j's ranges it holds, ``applied[j]`` the last its filter
    took, ``held[j]`` those ranges (step -> position x, y metres, range metres or None), ``told[n]``
    the ``known`` neighbour n last said it holds. What a message of step ``k`` brings counts from
    the start of step ``k + 1`` (:meth:`take`), whenever it arrived, as in the engine. Memory is
    bounded: ranges older than ``RELAY_KEPT_STEPS`` steps are dropped (never taken, never sent:
    their variance is widened by thousands of ``q``), so a message carries at most what is kept,
    and the newest ``MAX_RELAYED`` of them.
    """

    def __init__(self, robot: int, robots: int, window: int, kept_steps: int = RELAY_KEPT_STEPS) -> None:
        self.robot, self.robots = robot, robots
        self.known = [0] * robots
        self.applied = [0] * robots
        self.held: list[dict[int, tuple[float, float, float | None]]] = [{} for _ in range(robots)]
        self.told: dict[int, list[int]] = {}
        self.pending: dict[int, list[int]] = {}  # message step -> the known it brought
        self.pending_told: dict[tuple[int, int], list[int]] = {}  # (neighbour, message step) -> its known
        self.snapshots: dict[int, list[int]] = {}  # step -> known as the step began (its own range included)
        self.drift = Drift(window)
        self.kept_steps = kept_steps
        self.dropped = 0  # steps up to this one are dropped from ``held``

    def hear(self, sender: int, step: int, known: list[int], ranges: list[Relayed]) -> None:
        """A message of ``step`` from ring neighbour ``sender`` saying it holds ``known`` and carrying
        ``ranges``."""
        if len(known) != self.robots:
            return
        for source, at, x, y, value in ranges:
            if at > self.dropped and 0 <= source < self.robots:
                self.held[source].setdefault(at, (x, y, value))
        self.pending[step] = _merged(self.pending.get(step), known)
        self.pending_told[sender, step] = _merged(self.pending_told.get((sender, step)), known)

    def take(self, step: int, mean: FloatArray, range_sigma: float,
             process_noise: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Fold in what the messages of steps before ``step`` brought, then return the ranges held and
        not yet taken, now taken, as measurements of the target at ``step`` by a filter whose mean
        (2,) is ``mean`` (metres): origins (1, M, 2) moved by the estimated displacement since each
        was taken, ranges (1, M) metres (NaN: none) and variances (1, M) m^2, source by source,
        steps ascending (:meth:`RangeRelay.take` for one robot)."""
        for at in [at for at in self.pending if at < step]:
            self.known = _merged(self.known, self.pending.pop(at))
        for key in [key for key in self.pending_told if key[1] < step]:
            self.told[key[0]] = _merged(self.told.get(key[0]), self.pending_told.pop(key))
        velocity = self.drift.velocities(np.asarray(mean, dtype=float)[None])
        entries = [(source, at) for source in range(self.robots)
                   for at in range(max(self.applied[source], self.dropped) + 1, self.known[source] + 1)
                   if at in self.held[source]]
        self.applied = list(self.known)
        positions = np.array([self.held[source][at][:2] for source, at in entries], dtype=float).reshape(-1, 2)
        values = [self.held[source][at][2] for source, at in entries]
        ranges = np.array([np.nan if value is None else value for value in values], dtype=float)
        ages = np.array([step - at for _, at in entries], dtype=np.int64)
        origins = positions + velocity * ages[:, None]
        return origins[None], ranges[None], late_variance(range_sigma, process_noise, ages)[None]

    def record(self, step: int, position: tuple[float, float], value: float | None) -> None:
        """The robot's own range of ``step`` (metres, None: none) from ``position`` (metres): it holds
        and takes it; what it holds now is what its messages of the step say."""
        self.held[self.robot][step] = (position[0], position[1], value)
        self.known[self.robot] = self.applied[self.robot] = step
        self.snapshots[step] = list(self.known)
        self.snapshots.pop(step - SNAPSHOT_STEPS, None)
        cutoff = step - self.kept_steps
        while self.dropped < cutoff:
            self.dropped += 1
            for held in self.held:
                held.pop(self.dropped, None)

    def carried(self, step: int, receiver: int, base: list[int] | None) -> tuple[list[int], list[Relayed]]:
        """What a message of ``step`` to ``receiver`` carries: the known vector as ``step`` began (the
        oldest kept if that step is forgotten) and the ranges ``(base, known]`` of every source but
        the receiver (``base``: what the receiver is known to hold; None: nothing), the newest
        ``MAX_RELAYED`` at most."""
        known = self.snapshots.get(step) or self.snapshots[min(self.snapshots)]
        low = base or [0] * self.robots
        ranges: list[Relayed] = []
        for source in range(self.robots):
            if source == receiver:
                continue
            held = self.held[source]
            for at in range(max(low[source], self.dropped) + 1, known[source] + 1):
                if at in held:
                    x, y, value = held[at]
                    ranges.append((source, at, x, y, value))
        if len(ranges) > MAX_RELAYED:
            newest = sorted(ranges, key=lambda entry: entry[1])[-MAX_RELAYED:]
            ranges = sorted(newest, key=lambda entry: (entry[0], entry[1]))
        return list(known), ranges


def _merged(before: list[int] | None, known: list[int]) -> list[int]:
    """The elementwise maximum of two known vectors (``before`` None: ``known``)."""
    return list(known) if before is None else [max(a, b) for a, b in zip(before, known, strict=True)]
