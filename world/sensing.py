"""The range sensor: noisy distances from robots to the target (metres).

``z_i = ||p_i - o|| + v_i``, ``v_i ~ N(0, sigma^2)``, and no measurement (NaN) beyond the sensing
range ``r_s``. Noise comes from ``numpy.random.default_rng([seed, SENSOR_STREAM])``, drawn for every
robot every step whether or not it is in range, so the engine and the world process draw the same
numbers for the same seed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ringtrack.world.geometry import FloatArray

SENSOR_STREAM = 1


class RangeSensor:
    def __init__(self, sigma: float, max_range: float | None, seed: int) -> None:
        self.sigma = sigma
        self.max_range = max_range
        self.rng = np.random.default_rng([seed, SENSOR_STREAM])

    def measure(self, positions: ArrayLike, target: ArrayLike) -> FloatArray:
        """Ranges from each robot at ``positions`` (N, 2) to ``target`` (2,), NaN beyond range."""
        positions = np.asarray(positions, dtype=float)
        distance = np.linalg.norm(np.asarray(target, dtype=float) - positions, axis=-1)
        measured = distance + self.rng.normal(0.0, 1.0, len(positions)) * self.sigma
        if self.max_range is not None:
            measured = np.where(distance <= self.max_range, measured, np.nan)
        return measured
