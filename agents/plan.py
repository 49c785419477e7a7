"""The plan strategy: self-triggered polling where a reply carries the replier's committed plan
(docs/algorithms.md section 17). Known stationary target only.

Between its own triggers a robot's motion depends only on its memory, and being polled does not
change that memory, so right after each trigger a robot can run its own guarded law forward and
knows its exact course until its next trigger ``T_j``. A reply at step ``k`` carries the position
``b = theta_j(k)`` and the plan ``(T', r-, r+, D)``: ``T' = min(T_j, k + H)`` (``k`` when ``j``
polls at ``k``), ``r-``/``r+`` the least and greatest of ``theta_j - b`` over ``k .. T'`` and
``D = theta_j(T') - b`` (radians). The requester then knows ``j`` lies in
:func:`prediction_set` at every later step; with ``r = D = 0`` and ``T' = k`` that is the paper's
``b +- omega_max tau``.

:class:`PlanController` holds the memory and the committed course of any number of robots (leading
shape ``S``: ``()`` in a robot process, ``(trials, robots)`` in the engine) with the method shape of
:class:`agents.controller.MidpointController`, plus :meth:`PlanController.offer` (the plan a reply
carries) and a ``plans`` argument of :meth:`PlanController.receive`. Its own course is computed by
the same function that decides a live step (:func:`decide`), and the robot then follows that course,
so what it promised is what it does. Angles are radians about the target; steps are 1-based.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.controller import CentreUncertainty
from ringtrack.agents.laws import Trigger, fresh_step, guarded_step, set_trigger_reasons
from ringtrack.agents.strategy import Controller, Received, Strategy, StrategyError, StrategyParameter
from ringtrack.world.geometry import ConvexRegion, FloatArray, angle_of
from ringtrack.world.params import ControlParams
from ringtrack.world.ring import local_frame, midpoint

if TYPE_CHECKING:
    from ringtrack.world.scenario import Scenario

IntArray = NDArray[np.int64]
PLAN_HORIZON = 10  # default H, steps (README: chosen by measurement)
MAX_PLAN_HORIZON = 10_000  # steps; a controller holds H + 2 angles per robot


class Plan(NamedTuple):
    """A plan as a reply carries it (arrays of one shape): ``until`` = ``T'`` (step), ``low`` = ``r-``,
    ``high`` = ``r+``, ``shift`` = ``D`` (radians relative to the replier's angle at the reply's step)."""

    until: IntArray
    low: FloatArray
    high: FloatArray
    shift: FloatArray


def no_plan(step: ArrayLike) -> Plan:
    """The plan of a robot that polls at ``step`` (or of a reply that carries none): the paper's rule."""
    step = np.asarray(step, dtype=np.int64)
    zeros = np.zeros(step.shape)
    return Plan(step, zeros, zeros, zeros)


def prediction_set(step: ArrayLike, since: ArrayLike, plan: Plan,
                   params: ControlParams) -> tuple[FloatArray, FloatArray]:
    """Centre and half-width (radians, relative to the replied angle ``b``) of the set a neighbour
    lies in at ``step``, from its reply of step ``since`` carrying ``plan``, with ``w = omega_max dt``:
    ``[max(r-, -w (k - since)), min(r+, w (k - since))]`` while ``k <= T'``, ``D +- w (k - T')`` after.
    Widths are computed as ``omega_max * steps * dt``, as the self-triggered rule computes its reach."""
    step = np.asarray(step)
    reach = params.omega_max * (step - np.asarray(since)) * params.dt
    low = np.maximum(plan.low, -reach)
    high = np.minimum(plan.high, reach)
    grown = params.omega_max * (step - plan.until) * params.dt
    within = step <= plan.until
    centre = np.where(within, (low + high) / 2.0, plan.shift)
    half_width = np.where(within, (high - low) / 2.0, grown)
    return centre, half_width


class Memory(NamedTuple):
    """What a robot remembers of one neighbour: the replied angle ``angle`` (radians about the
    target), the reply's step ``since``, its plan, and whether anything is known (``known``)."""

    angle: FloatArray
    since: IntArray
    plan: Plan
    known: NDArray[np.bool_]


class Decision(NamedTuple):
    """One step of a robot: trigger mask, ``gV - theta`` and the step ``Delta theta`` (radians) it
    takes if it does not poll (or, after polling, with the memory refreshed)."""

    reasons: IntArray
    offset: FloatArray
    step: FloatArray


def decide(step: ArrayLike, theta: ArrayLike, before: Memory, after: Memory, params: ControlParams) -> Decision:
    """The plan strategy's decision at ``step`` for a robot at ``theta`` remembering its predecessor
    ``before`` and successor ``after``: the prediction sets' centres and half-widths replace the
    remembered angles and ``omega_max tau`` in ``gV``, ``ubd = (phi_- + phi_+) / 4``, T1-T3 and both
    motion laws (fresh when both neighbours replied this step). A side of which nothing is known
    polls (``UNKNOWN``) and holds still. Shared by the live robot and its forward simulation."""
    theta = np.asarray(theta, dtype=float)
    centre_minus, phi_minus = prediction_set(step, before.since, before.plan, params)
    centre_plus, phi_plus = prediction_set(step, after.since, after.plan, params)
    # The set centres in the robot's frame (a centre, unlike an old position, is never past the robot
    # while T2 and T3 do not hold).
    m_minus, m_plus = local_frame(theta, before.angle + centre_minus, after.angle + centre_plus)
    ubd = (phi_minus + phi_plus) / 4.0
    reasons = set_trigger_reasons(theta, m_minus, m_plus, phi_minus, phi_plus, ubd, params.sigma)
    offset = midpoint(m_minus, theta, m_plus) - theta
    fresh = (np.asarray(before.since) == step) & (np.asarray(after.since) == step)
    motion = np.where(fresh, fresh_step(offset, params), guarded_step(offset, ubd, params.max_step))
    unknown = ~(before.known & after.known)
    reasons = np.where(unknown, reasons | int(Trigger.UNKNOWN), reasons)
    return Decision(reasons, offset, np.where(unknown, 0.0, motion))


class PlanController:
    """Memory, committed course and decisions of the plan strategy for robots of leading shape ``S``.

    The course is a ring buffer of the next ``H + 2`` angles (``course``, indexed by step modulo its
    length): angles are known up to step ``end``, decisions (all "no poll") for the steps before it,
    and where ``stopped`` the decision at ``end`` is a poll (``T_j = end``). It is extended lazily,
    as far as the robot's own step or a reply's horizon needs. ``horizon`` is ``H`` (steps).
    """

    def __init__(self, region: ConvexRegion, params: ControlParams, own_position: ArrayLike,
                 horizon: int = PLAN_HORIZON) -> None:
        self.region = region
        self.params = params
        self.horizon = horizon
        self.own_position: FloatArray = np.array(own_position, dtype=float)
        shape = self.own_position.shape[:-1]
        self.predecessor_position: FloatArray = self.own_position.copy()
        self.successor_position: FloatArray = self.own_position.copy()
        empty = Memory(np.zeros(shape), np.ones(shape, dtype=np.int64), no_plan(np.ones(shape, dtype=np.int64)),
                       np.zeros(shape, dtype=bool))
        self.before, self.after = empty, empty
        self.guaranteed_offset: FloatArray = np.zeros(shape)
        self.offset_known: NDArray[np.bool_] = np.zeros(shape, dtype=bool)
        self.centre: FloatArray = np.zeros(2)
        self.theta: FloatArray = np.zeros(shape)
        self.step = 0
        length = self.horizon + 2
        self.course: FloatArray = np.zeros((*shape, length))
        self.end: IntArray = np.zeros(shape, dtype=np.int64)
        self.stopped: NDArray[np.bool_] = np.zeros(shape, dtype=bool)
        self.valid: NDArray[np.bool_] = np.zeros(shape, dtype=bool)  # the course follows from the memory
        self.reasons: IntArray = np.zeros(shape, dtype=np.int64)
        self.decided_reasons: IntArray = np.zeros(self.course.shape, dtype=np.int64)  # per course slot
        self.decided_offsets: FloatArray = np.zeros(self.course.shape)  # gV - theta per course slot

    # ------------------------------------------------------------------ memory
    @property
    def predecessor_age(self) -> IntArray:
        """Steps since the predecessor's last reply."""
        return self.step - self.before.since

    @property
    def successor_age(self) -> IntArray:
        """Steps since the successor's last reply."""
        return self.step - self.after.since

    @property
    def predecessor_known(self) -> NDArray[np.bool_]:
        return self.before.known

    @property
    def successor_known(self) -> NDArray[np.bool_]:
        return self.after.known

    def sets(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """The current prediction sets as absolute angles (radians about the target, the replied
        angle plus the offsets): predecessor low and high, successor low and high."""
        bounds = []
        for memory in (self.before, self.after):
            centre, half_width = prediction_set(self.step, memory.since, memory.plan, self.params)
            bounds += [memory.angle + centre - half_width, memory.angle + centre + half_width]
        return bounds[0], bounds[1], bounds[2], bounds[3]

    # ------------------------------------------------------------------ the step
    def observe(self, step: int, own_position: ArrayLike, centre: ArrayLike,
                reach: tuple[ArrayLike, ArrayLike] = (True, True),
                uncertainty: CentreUncertainty | None = None) -> IntArray:
        """Start step ``step`` at ``own_position`` seen from ``centre`` (the known target) and return
        the :class:`Trigger` mask: ``START`` at step 1, else the committed course's decision.
        ``reach`` and ``uncertainty`` are accepted for the shape of :class:`MidpointController` only:
        the plan strategy runs without a communication range, about the known target."""
        self.step = step
        self.own_position = np.asarray(own_position, dtype=float)
        self.recentre(centre)
        if step == 1:
            self.reasons = np.full(self.theta.shape, int(Trigger.START))
            self.stopped = np.ones(self.theta.shape, dtype=bool)
            self.end = np.ones(self.theta.shape, dtype=np.int64)
            self.valid = np.ones(self.theta.shape, dtype=bool)
            self.offset_known = np.zeros(self.theta.shape, dtype=bool)
            self.guaranteed_offset = np.zeros(self.theta.shape)
            return self.reasons
        self._restart(~self.valid | (self.end < step), self.theta)
        self._extend(step, inclusive=True)
        slot = step % self.course.shape[-1]
        self.reasons = self.decided_reasons[..., slot].copy()
        self.guaranteed_offset = self.decided_offsets[..., slot].copy()
        self.offset_known = self.before.known & self.after.known
        return self.reasons

    def recentre(self, centre: ArrayLike) -> None:
        """See the ring from ``centre`` (the known target, metres)."""
        self.centre = np.asarray(centre, dtype=float)
        self.theta = angle_of(self.own_position, self.centre)

    def offer(self) -> Plan:
        """The plan a reply of the current step carries (after :meth:`observe`): no plan where the
        robot polls now, else its course from now to ``T' = min(T_j, step + H)``."""
        step = self.step
        polls = self.reasons != 0
        self._extend(step + self.horizon, inclusive=False)
        length = self.course.shape[-1]
        ahead = np.arange(self.horizon + 1)
        angles = np.take(self.course, (step + ahead) % length, axis=-1)
        until = np.where(self.stopped, np.minimum(self.end, step + self.horizon), step + self.horizon)
        until = np.where(polls, step, until)
        relative = angles - angles[..., :1]
        inside = ahead <= (until - step)[..., None]
        low = np.where(inside, relative, np.inf).min(axis=-1)
        high = np.where(inside, relative, -np.inf).max(axis=-1)
        shift = np.take_along_axis(relative, (until - step)[..., None], axis=-1)[..., 0]
        return Plan(until.astype(np.int64), np.where(polls, 0.0, low), np.where(polls, 0.0, high),
                    np.where(polls, 0.0, shift))

    def receive(
        self,
        predecessor_position: ArrayLike,
        successor_position: ArrayLike,
        predecessor_fresh: ArrayLike = True,
        successor_fresh: ArrayLike = True,
        predecessor_age: ArrayLike = 0,
        successor_age: ArrayLike = 0,
        plans: tuple[Plan | None, Plan | None] = (None, None),
    ) -> None:
        """Store the replies where ``*_fresh`` holds: positions (metres), their ages in steps (0: of
        this step) and the plans they carry (None: the paper's rule, no plan)."""
        memories = []
        for memory, position, fresh, age, plan in (
            (self.before, predecessor_position, predecessor_fresh, predecessor_age, plans[0]),
            (self.after, successor_position, successor_fresh, successor_age, plans[1]),
        ):
            fresh = np.asarray(fresh, dtype=bool)
            since = self.step - np.asarray(age, dtype=np.int64)
            plan = no_plan(np.broadcast_to(since, fresh.shape)) if plan is None else plan
            memories.append(Memory(
                np.where(fresh, angle_of(np.asarray(position, dtype=float), self.centre), memory.angle),
                np.where(fresh, since, memory.since),
                Plan(*(np.where(fresh, new, old) for new, old in zip(plan, memory.plan, strict=True))),
                memory.known | fresh,
            ))
        self.predecessor_position = np.where(np.asarray(predecessor_fresh)[..., None], predecessor_position,
                                             self.predecessor_position)
        self.successor_position = np.where(np.asarray(successor_fresh)[..., None], successor_position,
                                           self.successor_position)
        self.before, self.after = memories

    def forget(self, predecessor: ArrayLike = False, successor: ArrayLike = False) -> None:
        """Drop a side whose neighbour changed; the course no longer follows from the memory."""
        predecessor, successor = np.asarray(predecessor, dtype=bool), np.asarray(successor, dtype=bool)
        self.before = self.before._replace(known=self.before.known & ~predecessor)
        self.after = self.after._replace(known=self.after.known & ~successor)
        self.valid = self.valid & ~(predecessor | successor)

    def goal(self, reach: tuple[ArrayLike, ArrayLike] | None = None,
             communication_range: float | None = None) -> FloatArray:
        """The boundary point (metres) to move to this step: the committed course's next angle, or,
        where the robot polled, the step :func:`decide` takes with what came back (a new course
        starts from there)."""
        length = self.course.shape[-1]
        polled = self.stopped & (self.end == self.step)
        live = decide(self.step, self.theta, self.before, self.after, self.params)
        following = np.take(self.course, (self.step + 1) % length, axis=-1)
        target = np.where(polled, self.theta + live.step, following)
        if self.step == 1:
            self.guaranteed_offset = live.offset
            self.offset_known = self.before.known & self.after.known
        self._restart(polled, target, self.step + 1)
        return self.region.boundary_point(target, self.centre)

    # ------------------------------------------------------------------ the course
    def _restart(self, where: ArrayLike, theta: ArrayLike, step: int | None = None) -> None:
        """Begin a new course at ``step`` (default the current one) from angle ``theta``."""
        where = np.asarray(where, dtype=bool)
        if not where.any():
            return
        step = self.step if step is None else step
        slot = step % self.course.shape[-1]
        self.course[..., slot] = np.where(where, theta, self.course[..., slot])
        self.end = np.where(where, step, self.end)
        self.stopped = self.stopped & ~where
        self.valid = self.valid | where

    def _extend(self, until: int, inclusive: bool) -> None:
        """Simulate the course forward until its angles reach step ``until`` (``inclusive``: until
        the decision at ``until`` is known too) or the robot's next poll."""
        length = self.course.shape[-1]
        while True:
            need = ~self.stopped & ((self.end <= until) if inclusive else (self.end < until))
            if not need.any():
                return
            slot = self.end % length
            theta = np.take_along_axis(self.course, slot[..., None], axis=-1)[..., 0]
            decision = decide(self.end, theta, self.before, self.after, self.params)
            _store(self.decided_reasons, slot, need, decision.reasons)
            _store(self.decided_offsets, slot, need, decision.offset)
            polls = need & (decision.reasons != 0)
            moves = need & ~polls
            self.stopped = self.stopped | polls
            _store(self.course, (self.end + 1) % length, moves, theta + decision.step)
            self.end = np.where(moves, self.end + 1, self.end)


def _store(ring: NDArray, slot: IntArray, where: NDArray[np.bool_], values: ArrayLike) -> None:
    """``ring[..., slot] = values`` where ``where`` holds (one slot per robot, last axis)."""
    index = slot[..., None]
    current = np.take_along_axis(ring, index, axis=-1)[..., 0]
    np.put_along_axis(ring, index, np.where(where, values, current)[..., None], axis=-1)


class PlanStrategy(Strategy):
    """The self-triggered rule with plan-carrying replies (this module): its controller is a
    :class:`PlanController`, its replies carry :meth:`PlanController.offer` as four floats
    ``(T' - k, r-, r+, D)`` (steps ahead of the reply's step ``k``, then radians), all zero where
    the replier polls (so the reply goes as a plain one and is read as the paper's rule).

    It needs what makes a robot's motion between its triggers a function of its memory alone
    (:meth:`check`): a known stationary target and no communication range (whose reachability
    comes from the world each step)."""

    name = "plan"
    summary = "the paper's triggers; replies carry the replier's committed plan (known target)"
    label = "plan replies"
    estimation = "known"
    reply_fields = 4
    parameters = (
        StrategyParameter("plan_horizon", int, PLAN_HORIZON, units="steps", ge=0, le=MAX_PLAN_HORIZON,
                          help="the most steps ahead a reply's plan describes (H; 0: the paper's rule)"),
    )
    plan_horizon: int

    def check(self, scenario: Scenario) -> None:
        if scenario.estimation.mode != "known":
            raise StrategyError("the plan strategy needs a known stationary target (estimation.mode = 'known'); "
                                "use 'self' to estimate")
        if scenario.communication_range is not None:
            raise StrategyError("the plan strategy needs unlimited communication; "
                                "unset limits.communication_range or use 'self'")
        super().check(scenario)

    def controller(self, region: ConvexRegion, params: ControlParams, own_position: ArrayLike) -> Controller:
        # Its ages and knowledge are read-only views of its records, where the protocol has plain attributes.
        return PlanController(region, params, own_position, self.plan_horizon)  # type: ignore[return-value]

    def reply_content(self, controller: PlanController) -> FloatArray:
        plan = controller.offer()
        ahead = (plan.until - controller.step).astype(float)
        return np.stack([ahead, plan.low, plan.high, plan.shift], axis=-1)

    def receive(self, controller: PlanController, predecessor: Received, successor: Received) -> None:
        plans = []
        for side in (predecessor, successor):
            assert side.content is not None
            since = controller.step - side.age  # the step the reply describes
            ahead = np.rint(side.content[..., 0]).astype(np.int64)
            plans.append(Plan(since + ahead, side.content[..., 1], side.content[..., 2], side.content[..., 3]))
        controller.receive(predecessor.position, successor.position, predecessor.fresh, successor.fresh,
                           predecessor.age, successor.age, plans=(plans[0], plans[1]))
