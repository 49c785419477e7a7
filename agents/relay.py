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
  ``VELOCITY_WINDOW_S`` seconds (:meth:`RangeRelay.velocities`), and
* what that estimate misses widens the range's variance by the random walk's ``age q``
  (:func:`late_variance`).

(docs/algorithms.md section 20.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ringtrack.world.geometry import FloatArray
from ringtrack.world.ring import predecessor_values, successor_values

VELOCITY_WINDOW_S = 5.0  # s: a robot's velocity estimate is its mean's drift over this long


def late_variance(range_sigma: float, process_noise: float, age: NDArray[np.int64]) -> FloatArray:
    """The variance (m^2) of a range taken ``age`` steps ago as a measurement of the target now: the
    sensor's ``range_sigma^2`` (m^2) plus the random walk's ``age q`` (``q`` m^2 per step) along the
    line of sight. The motion since is treated as noise of that range alone (it is shared by every
    late range and the prior): exact for a range of this step, an approximation for older ones."""
    return np.asarray(range_sigma**2 + process_noise * age, dtype=float)


class RangeRelay:
    """Which ranges each robot of a batch of rings holds, and the ranges themselves.

    ``known[t, r, j]`` is the last step of robot j's ranges that robot r of trial t holds (it holds
    all steps up to it; 0: none), ``applied[t, r, j]`` the last its filter took. Ranges (metres, NaN:
    none) and the positions they were taken from (metres) are kept for ``steps`` steps, and each
    robot's mean (metres) for the last ``window`` steps (:meth:`velocities`).
    """

    def __init__(self, trials: int, robots: int, steps: int, window: int) -> None:
        self.known = np.zeros((trials, robots, robots), dtype=np.int64)
        self.applied = np.zeros((trials, robots, robots), dtype=np.int64)
        self.ranges = np.full((steps + 1, trials, robots), np.nan)
        self.positions = np.zeros((steps + 1, trials, robots, 2))
        self.window = max(1, window)
        self.means: list[FloatArray] = []  # the robots' means (T*N, 2) at the last window + 1 steps
        self._own = np.eye(robots, dtype=bool)[None]

    def velocities(self, means: FloatArray) -> FloatArray:
        """Each robot's estimate of the target's velocity (T*N, 2), metres per step: the drift of its
        ``means`` (T*N, 2, this step's, before its update) over the last ``window`` steps (fewer at
        the start; zero at the first)."""
        self.means.append(means)
        if len(self.means) > self.window + 1:
            self.means.pop(0)
        return (means - self.means[0]) / max(1, len(self.means) - 1)

    def take(
        self, step: int, means: FloatArray, range_sigma: float, process_noise: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The ranges each robot holds and its filter has not taken, now marked taken, as measurements
        of the target at ``step`` by filters whose means (T*N, 2) are ``means``: origins (T*N, M, 2)
        moved by the estimated displacement since each was taken, ranges (T*N, M) (NaN pads rows to
        the longest, M) and variances (T*N, M) (:func:`late_variance`)."""
        trials, robots, _ = self.known.shape
        velocity = self.velocities(means)
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
