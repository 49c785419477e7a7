"""What a robot remembers about its ring neighbours and the step-by-step decisions it takes.

One :class:`MidpointController` holds the memory of any number of robots as arrays with a common
leading shape ``S``: ``()`` for the single robot of a robot process, ``(N,)`` for a team, ``(T, N)``
for a batch of trials in the engine. Both call the same methods in the same order every step::

    reasons = controller.observe(step, own_position, centre)   # ages += 1, evaluate the trigger
    # ... where reasons != 0: ask both neighbours for their step-start positions ...
    controller.receive(reasons != 0, predecessor_position, successor_position)
    goal = controller.goal(own_position, centre)                # boundary point to move to

Neighbours are remembered by *position* (metres) and angles are recomputed from the current centre
every step (ALGORITHMS.md section 2), so the same code serves a known stationary target and a moving
estimate. Ages are integer step counts.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agents.laws import ControlParams, Trigger, angular_step, trigger_reasons
from agents.ring import local_frame, midpoint
from world.geometry import ConvexRegion, FloatArray, angle_of


class MidpointController:
    """Memory and decisions of the constant or self-triggered midpoint strategy.

    ``predecessor_position``/``successor_position`` (shape ``S + (2,)``) are the remembered
    neighbour positions, ``predecessor_age``/``successor_age`` (shape ``S``, int) their ages in steps,
    and ``guaranteed_offset`` the last observed ``gV - theta`` (radians) from memory as it was before
    any exchange, the quantity of the paper's self-triggered Cerr.
    """

    def __init__(
        self,
        region: ConvexRegion,
        params: ControlParams,
        predecessor_position: ArrayLike,
        successor_position: ArrayLike,
    ) -> None:
        self.region = region
        self.params = params
        self.predecessor_position: FloatArray = np.array(predecessor_position, dtype=float)
        self.successor_position: FloatArray = np.array(successor_position, dtype=float)
        shape = self.predecessor_position.shape[:-1]
        self.predecessor_age: NDArray[np.int64] = np.zeros(shape, dtype=np.int64)
        self.successor_age: NDArray[np.int64] = np.zeros(shape, dtype=np.int64)
        self.guaranteed_offset: FloatArray = np.zeros(shape)

    def view(self, own_position: ArrayLike, centre: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(theta, m_minus, m_plus)``: own angle and remembered neighbour angles (radians, local
        frame) seen from ``centre``."""
        theta = angle_of(own_position, centre)
        m_minus, m_plus = local_frame(
            theta, angle_of(self.predecessor_position, centre), angle_of(self.successor_position, centre)
        )
        return theta, m_minus, m_plus

    def observe(self, step: int, own_position: ArrayLike, centre: ArrayLike) -> NDArray[np.int64]:
        """Start step ``step`` (1-based): age the memory and return the :class:`Trigger` mask.

        Step 1 always polls (``START``); the constant strategy polls every step (``SCHEDULE``); the
        self-triggered strategy polls where T1, T2 or T3 holds.
        """
        if step > 1:
            self.predecessor_age += 1
            self.successor_age += 1
        theta, m_minus, m_plus = self.view(own_position, centre)
        self.guaranteed_offset = midpoint(m_minus, theta, m_plus) - theta
        if step == 1:
            return np.full(theta.shape, int(Trigger.START))
        if self.params.strategy == "constant":
            return np.full(theta.shape, int(Trigger.SCHEDULE))
        return trigger_reasons(theta, m_minus, m_plus, self.predecessor_age, self.successor_age, self.params)

    def receive(self, polled: ArrayLike, predecessor_position: ArrayLike, successor_position: ArrayLike) -> None:
        """Store the neighbours' step-start positions where ``polled`` is true and reset those ages."""
        polled = np.asarray(polled, dtype=bool)
        self.predecessor_position = np.where(polled[..., None], predecessor_position, self.predecessor_position)
        self.successor_position = np.where(polled[..., None], successor_position, self.successor_position)
        self.predecessor_age = np.where(polled, 0, self.predecessor_age)
        self.successor_age = np.where(polled, 0, self.successor_age)

    def goal(self, own_position: ArrayLike, centre: ArrayLike) -> FloatArray:
        """The boundary point (metres) to move to this step: ``phi_centre^{-1}(theta + Delta theta)``.

        Memory refreshed this step (both ages 0) takes the fresh-information law, stale memory the
        guarded law of Algorithm 1.
        """
        theta, m_minus, m_plus = self.view(own_position, centre)
        fresh = (self.predecessor_age == 0) & (self.successor_age == 0)
        step = angular_step(
            theta, m_minus, m_plus, self.predecessor_age, self.successor_age, fresh, self.params
        )
        return self.region.boundary_point(theta + step, centre)
