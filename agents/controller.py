"""What a robot remembers about its ring neighbours and the step-by-step decisions it takes.

One :class:`MidpointController` holds the memory of any number of robots as arrays with a common
leading shape ``S``: ``()`` for the single robot of a robot process, ``(N,)`` for a team, ``(T, N)``
for a batch of trials in the engine (a single robot's memory is numpy scalars, not 0-d arrays:
their arithmetic skips numpy's cost per call). Both call the same methods in the same order every step::

    reasons = controller.observe(step, own_position, centre)   # age the memory, evaluate the trigger
    # ... where reasons != 0: ask both neighbours for their step-start positions ...
    controller.receive(predecessor_position, successor_position, reasons != 0, reasons != 0)
    controller.recentre(fused_centre)                           # only when the centre changed
    goal = controller.goal()                                    # boundary point to move to

Neighbours are remembered by *position* (metres) and their angles are recomputed from the current
centre every step (docs/algorithms.md section 2), so the same code serves a known stationary target and a
moving estimate. Ages are integer step counts.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.laws import START_BIT, UNKNOWN_BIT, Mask, angular_step, trigger_reasons
from ringtrack.agents.limits import boundary_stretch, clip_to_range, range_limited_step
from ringtrack.world.elementwise import anywhere, choose, scalar
from ringtrack.world.geometry import ConvexRegion, FloatArray, angle_of
from ringtrack.world.params import ControlParams
from ringtrack.world.ring import local_frame, midpoint


class CentreUncertainty(NamedTuple):
    """How well robots know the centre they steer about (a trigger rule may read it,
    :attr:`agents.strategy.Strategy.reads_uncertainty`): the ``covariance`` (m^2, ``S + (2, 2)``) of
    each robot's estimate, and ``steady_variance`` (m^2 per axis) what a filter taking every robot's
    range every step settles to (:func:`world.target.steady_variance`)."""

    covariance: FloatArray
    steady_variance: float


def self_triggered_rule(controller: MidpointController) -> Mask:
    """The self-triggered rule (T1-T3) from a controller's view (``theta``, ``m_minus``, ``m_plus``
    radians, ages in steps): the trigger rule of a controller given none."""
    return trigger_reasons(controller.theta, controller.m_minus, controller.m_plus, controller.predecessor_age,
                           controller.successor_age, controller.params)


class MidpointController:
    """Memory and decisions of the midpoint strategies; ``rule(controller)`` is the trigger rule of
    steps after the first (default: the self-triggered rule, :func:`agents.laws.trigger_reasons`;
    a strategy gives its own, :meth:`agents.strategy.Strategy.controller`).

    ``predecessor_position``/``successor_position`` (shape ``S + (2,)``) are the remembered
    neighbour positions, ``predecessor_age``/``successor_age`` (shape ``S``, int) their ages in steps,
    and ``guaranteed_offset`` the last observed ``gV - theta`` (radians) from memory as it was before
    polling, the quantity of the paper's self-triggered Cerr, with ``offset_known`` whether that
    memory held something of both neighbours (else the offset is no value of the ring). A new
    controller knows nothing: its memory holds its own position until the exchange of step 1, after
    which ``guaranteed_offset`` is the exact step-1 offset.

    The current view (``theta``, ``m_minus``, ``m_plus`` in radians, robot-local frame, seen from
    ``centre``) is set by :meth:`observe` and kept up to date by :meth:`receive` and :meth:`recentre`.
    """

    def __init__(self, region: ConvexRegion, params: ControlParams, own_position: ArrayLike,
                 rule: Callable[[Any], Mask] | None = None) -> None:
        self.region = region
        self.params = params
        self.rule = rule or self_triggered_rule
        self.own_position: FloatArray = np.array(own_position, dtype=float)
        self.predecessor_position: FloatArray = self.own_position.copy()
        self.successor_position: FloatArray = self.own_position.copy()
        shape = self.own_position.shape[:-1]
        self._one_robot = shape == ()  # a robot process's memory: scalars, decided in plain Python
        self.predecessor_age: NDArray[np.int64] = scalar(np.zeros(shape, dtype=np.int64))
        self.successor_age: NDArray[np.int64] = scalar(np.zeros(shape, dtype=np.int64))
        self.guaranteed_offset: FloatArray = scalar(np.zeros(shape))
        self.offset_known: NDArray[np.bool_] = scalar(np.zeros(shape, dtype=bool))
        # Whether anything is known of each neighbour: not before the first exchange, nor after the
        # neighbour changed until it answers; a robot polls (UNKNOWN) and holds still meanwhile.
        self.predecessor_known: NDArray[np.bool_] = scalar(np.zeros(shape, dtype=bool))
        self.successor_known: NDArray[np.bool_] = scalar(np.zeros(shape, dtype=bool))
        self.centre: FloatArray = np.zeros(2)
        self.theta: FloatArray = scalar(np.zeros(shape))
        self.m_minus: FloatArray = scalar(np.zeros(shape))
        self.m_plus: FloatArray = scalar(np.zeros(shape))
        self.uncertainty: CentreUncertainty | None = None
        self.step = 0

    def observe(self, step: int, own_position: ArrayLike, centre: ArrayLike,
                reach: tuple[ArrayLike, ArrayLike] = (True, True),
                uncertainty: CentreUncertainty | None = None) -> Mask:
        """Start step ``step`` (1-based) at ``own_position`` seen from ``centre``: age the memory and
        return the :class:`Trigger` mask.

        Step 1 always polls (``START``); later steps poll where the strategy's ``rule`` says so
        (:meth:`agents.strategy.Strategy.triggers`: the constant strategy every step, ``SCHEDULE``;
        the self-triggered one where T1, T2 or T3 holds); any strategy polls while nothing is
        known of a neighbour that is within ``reach`` (predecessor, successor) (``UNKNOWN``).
        ``uncertainty`` is what the rule may know of the estimate of ``centre`` (kept as
        :attr:`uncertainty` until the next step).
        """
        self.uncertainty = uncertainty
        reasons = self._reasons(step, own_position, centre)
        unknown = self._unknown(*reach)
        return choose(unknown & ((reasons & START_BIT) == 0), reasons | UNKNOWN_BIT, reasons)

    def _unknown(self, reach_minus: ArrayLike, reach_plus: ArrayLike) -> NDArray[np.bool_] | bool:
        """Where nothing is known of a neighbour within reach (predecessor, successor)."""
        if self._one_robot:
            return ((not self.predecessor_known and bool(reach_minus))
                    or (not self.successor_known and bool(reach_plus)))
        reach_minus, reach_plus = np.asarray(reach_minus), np.asarray(reach_plus)
        return (~self.predecessor_known & reach_minus) | (~self.successor_known & reach_plus)

    def _reasons(self, step: int, own_position: ArrayLike, centre: ArrayLike) -> Mask:
        if step > 1:
            self.predecessor_age += step - self.step
            self.successor_age += step - self.step
        self.step = step
        self.own_position = np.asarray(own_position, dtype=float)
        self.recentre(centre)
        self._take_offset()
        if step == 1:
            return np.full(self.theta.shape, START_BIT)
        return self.rule(self)

    def _take_offset(self) -> None:
        self.guaranteed_offset = midpoint(self.m_minus, self.theta, self.m_plus) - self.theta
        self.offset_known = self.predecessor_known & self.successor_known

    def recentre(self, centre: ArrayLike) -> None:
        """See the ring from ``centre`` (the target or its estimate, metres)."""
        self.centre = np.asarray(centre, dtype=float)
        self.theta = angle_of(self.own_position, self.centre)
        self._remembered_angles()

    def _remembered_angles(self) -> None:
        self.m_minus, self.m_plus = local_frame(
            self.theta, angle_of(self.predecessor_position, self.centre), angle_of(self.successor_position, self.centre)
        )

    def receive(
        self,
        predecessor_position: ArrayLike,
        successor_position: ArrayLike,
        predecessor_fresh: ArrayLike = True,
        successor_fresh: ArrayLike = True,
        predecessor_age: ArrayLike = 0,
        successor_age: ArrayLike = 0,
    ) -> None:
        """Store replied neighbour positions where ``*_fresh`` holds, with their ages in steps (0 for
        a reply describing the start of the current step); the other side keeps its older memory.
        Where nothing came at all, the remembered angles stand (the same positions from the same centre)."""
        came = False
        for side, position, fresh, age in (
            ("predecessor", predecessor_position, predecessor_fresh, predecessor_age),
            ("successor", successor_position, successor_fresh, successor_age),
        ):
            if self._one_robot:
                if fresh:
                    setattr(self, f"{side}_position", np.asarray(position, dtype=float))
                    setattr(self, f"{side}_age", scalar(np.asarray(age, dtype=np.int64)))
                    setattr(self, f"{side}_known", np.True_)
                    came = True
                continue
            fresh = np.asarray(fresh, dtype=bool)
            setattr(self, f"{side}_position", np.where(fresh[..., None], position, getattr(self, f"{side}_position")))
            setattr(self, f"{side}_age", np.where(fresh, age, getattr(self, f"{side}_age")))
            setattr(self, f"{side}_known", getattr(self, f"{side}_known") | fresh)
            came = came or anywhere(fresh)
        if came:
            self._remembered_angles()

    def keep(self, robots: NDArray[np.intp]) -> None:
        """Keep the memory of the robots at ``robots`` only (an index along the last axis of the
        leading shape ``S``): the others left the batch."""
        axis = np.ndim(self.theta) - 1
        for name in ("own_position", "predecessor_position", "successor_position", "predecessor_age", "successor_age",
                     "guaranteed_offset", "offset_known", "predecessor_known", "successor_known", "centre", "theta",
                     "m_minus", "m_plus"):
            setattr(self, name, np.take(getattr(self, name), robots, axis=axis))
        if self.uncertainty is not None:
            self.uncertainty = self.uncertainty._replace(covariance=np.take(self.uncertainty.covariance, robots, axis))

    def forget(self, predecessor: ArrayLike = False, successor: ArrayLike = False) -> None:
        """Drop what is remembered of a side whose neighbour changed (the ring re-formed around a
        robot that left, or one that came back): that side is unknown until the new neighbour
        answers, so the robot polls and holds still meanwhile."""
        self.predecessor_known = self.predecessor_known & ~np.asarray(predecessor, dtype=bool)
        self.successor_known = self.successor_known & ~np.asarray(successor, dtype=bool)

    def goal(self, reach: tuple[ArrayLike, ArrayLike] | None = None,
             communication_range: float | None = None) -> FloatArray:
        """The boundary point (metres) to move to this step: ``phi_centre^{-1}(theta + Delta theta)``.

        Memory refreshed this step (both ages 0) takes the fresh-information law, stale memory the
        guarded law of Algorithm 1 with ``ubd = omega_max (tau_minus + tau_plus) / 4``. With a
        ``communication_range`` (metres) and ``reach`` (predecessor, successor reachable), the
        modified strategy of :mod:`agents.limits` applies.
        """
        if self.step == 1:
            self._take_offset()
        fresh = (self.predecessor_age == 0) & (self.successor_age == 0)
        step = angular_step(
            self.theta, self.m_minus, self.m_plus, self.predecessor_age, self.successor_age, fresh, self.params
        )
        reach_minus, reach_plus = (True, True) if reach is None else reach
        step = choose(self._unknown(reach_minus, reach_plus), 0.0, step)
        if communication_range is not None and reach is not None:
            step = range_limited_step(step, reach_minus, reach_plus, self.params.max_step)
            per_step = boundary_stretch(self.region, self.centre) * self.params.max_step
            anchors = [
                (self.predecessor_position, reach_minus, per_step * (self.predecessor_age + 1)),
                (self.successor_position, reach_plus, per_step * (self.successor_age + 1)),
            ]
            step = clip_to_range(self.region, self.centre, self.theta, step, anchors, communication_range)
        return self.region.boundary_point(self.theta + step, self.centre)
