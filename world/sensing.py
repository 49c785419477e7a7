"""The range sensor: noisy distances from robots to the target (metres).

``z_i = ||p_i - o|| + v_i``, ``v_i ~ N(0, sigma^2)``, and no measurement (NaN) beyond the sensing
range ``r_s``. Noise comes from ``numpy.random.default_rng([seed, SENSOR_STREAM])``, drawn for every
robot every step whether or not it is in range, so the engine and the world process draw the same
numbers for the same seed. The standard normals are drawn ahead in blocks (a generator's stream is
the same drawn one value at a time or many), and one sensor serves a batch of trials at once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.geometry import FloatArray

SENSOR_STREAM = 1
BLOCK = 512  # standard normals drawn ahead per trial


class RangeSensors:
    """The range sensors of a batch of trials (one seed each), ``sigma`` and ``max_range`` metres
    (None: unlimited)."""

    def __init__(self, sigma: float, max_range: float | None, seeds: Sequence[int]) -> None:
        self.sigma = sigma
        self.max_range = max_range
        self.generators = [np.random.default_rng([seed, SENSOR_STREAM]) for seed in seeds]
        self.ahead = np.empty((len(self.generators), 0))

    def _noise(self, count: int) -> FloatArray:
        """The next ``count`` standard normals of every trial's stream, (T, count)."""
        if self.ahead.shape[1] < count:
            more = max(BLOCK, count)
            self.ahead = np.concatenate(
                [self.ahead, np.stack([generator.standard_normal(more) for generator in self.generators])], axis=1)
        noise, self.ahead = self.ahead[:, :count], self.ahead[:, count:]
        return noise

    def measure(self, positions: ArrayLike, targets: ArrayLike) -> FloatArray:
        """Ranges (T, N) from each robot at ``positions`` (T, N, 2) to its trial's target ``targets``
        (T, 2), NaN beyond range."""
        positions = np.asarray(positions, dtype=float)
        targets = np.asarray(targets, dtype=float)
        dx, dy = targets[:, None, 0] - positions[..., 0], targets[:, None, 1] - positions[..., 1]
        distance = np.sqrt(dx * dx + dy * dy)
        measured = distance + self._noise(positions.shape[1]) * self.sigma
        if self.max_range is not None:
            measured = np.where(distance <= self.max_range, measured, np.nan)
        return measured


class RangeSensor:
    """The range sensor of one run (:class:`RangeSensors` for one seed)."""

    def __init__(self, sigma: float, max_range: float | None, seed: int) -> None:
        self.sensors = RangeSensors(sigma, max_range, [seed])

    def measure(self, positions: ArrayLike, target: ArrayLike) -> FloatArray:
        """Ranges from each robot at ``positions`` (N, 2) to ``target`` (2,), NaN beyond range."""
        return self.sensors.measure(np.asarray(positions, dtype=float)[None], np.asarray(target, dtype=float)[None])[0]
