"""Communication strategies: what a robot asks, tells and does with what it hears, written once.

A strategy is a subclass of :class:`Strategy`. The in-process engine (:mod:`agents.engine`, every
robot of every trial at once: arrays of leading shape ``(T, N)``) and the robot protocol
(:mod:`agents.node`, one robot: leading shape ``()``) call the same methods in the same order, so a
strategy written once runs in both and a lockstep team equals the engine. Each step ``k`` a robot:

1. measures: its estimator folds in its range (the estimation mode's job);
2. hears (strategies that :attr:`~Strategy.listens`): its estimation step fuses, by covariance
   intersection, the beliefs its ring neighbours told it in step ``k - 1``, by a push or in a
   request, between the prediction and its own update (:meth:`Strategy.hear`);
3. observes: ``reasons = controller.observe(k, position, centre, reach)``; for ``k > 1`` the
   strategy's :meth:`~Strategy.triggers` decides whether the robot polls (step 1 always polls, and
   every strategy polls while it knows nothing of a reachable neighbour);
4. asks or tells: a robot that polls sends a request to both ring neighbours (carrying its belief
   when the strategy :attr:`~Strategy.listens`); one that does not poll pushes its belief to both
   when :meth:`~Strategy.wants_push` says so (strategies with :attr:`~Strategy.pushes`);
5. answers: a polled neighbour replies with its position at the start of step ``k``, its belief
   when it estimates, and :meth:`~Strategy.reply_content` (:attr:`~Strategy.reply_fields` floats
   read from its controller after it observed step ``k``);
6. receives: :meth:`~Strategy.receive` hands the replies (:class:`Received`) to the controller;
   a decentralized robot then fuses the replied beliefs;
7. moves: ``controller.goal(reach, r_c)``.

The memory and the motion law are the strategy's controller (:meth:`~Strategy.controller`, by
default :class:`agents.controller.MidpointController` with the strategy's trigger rule): any object
with the methods and attributes of :class:`Controller`, vectorised over a leading shape.

Strategies are found by name (:data:`REGISTRY`) or loaded from a Python file defining exactly one
subclass of :class:`Strategy` (:func:`strategy_for`); docs/strategies.md walks through writing one.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.controller import MidpointController, self_triggered_rule
from ringtrack.agents.laws import Mask, Trigger
from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.params import ControlParams, EstimationParams, Mode

if TYPE_CHECKING:
    from ringtrack.agents.estimation import Estimator
    from ringtrack.world.scenario import Scenario

Reasons = Mask  # a Trigger mask per robot (0: does not poll)


class Controller(Protocol):
    """What a strategy's controller offers (see :class:`agents.controller.MidpointController`): the
    memory of the robots of a leading shape ``S`` and the decisions of one step."""

    step: int
    theta: FloatArray
    centre: FloatArray
    predecessor_position: FloatArray
    successor_position: FloatArray
    predecessor_age: NDArray[np.int64]
    successor_age: NDArray[np.int64]
    guaranteed_offset: FloatArray
    offset_known: NDArray[np.bool_]

    def observe(self, step: int, own_position: ArrayLike, centre: ArrayLike,
                reach: tuple[ArrayLike, ArrayLike] = (True, True)) -> Reasons: ...

    def receive(self, predecessor_position: ArrayLike, successor_position: ArrayLike,
                predecessor_fresh: ArrayLike = True, successor_fresh: ArrayLike = True,
                predecessor_age: ArrayLike = 0, successor_age: ArrayLike = 0) -> None: ...

    def recentre(self, centre: ArrayLike) -> None: ...

    def forget(self, predecessor: ArrayLike = False, successor: ArrayLike = False) -> None: ...

    def goal(self, reach: tuple[ArrayLike, ArrayLike] | None = None,
             communication_range: float | None = None) -> FloatArray: ...


@dataclass(frozen=True)
class Received:
    """What came back from one side (predecessor or successor) of every robot of a step: the
    replied ``position`` (metres, ``S + (2,)``; the old memory where nothing came), whether it came
    (``fresh``, ``S``), the age of what it describes (steps, ``S``: 0 for the current step) and the
    strategy's ``content`` (``S + (reply_fields,)``, or None for a strategy whose replies carry nothing).
    A robot process's ``fresh`` and ``age`` are numpy scalars (``S = ()``)."""

    position: FloatArray
    fresh: NDArray[np.bool_] | np.bool_
    age: NDArray[np.int64] | np.int64
    content: FloatArray | None = None


class Strategy:
    """A communication strategy. Subclasses set :attr:`name` (and :attr:`summary`) and override
    what they change; every method is vectorised over the leading shape of its arrays."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    # The estimation mode the strategy needs (None: any); checked by :meth:`check`.
    estimation: ClassVar[Mode | None] = None
    # Requests carry the requester's belief and neighbours fuse the beliefs told them (step 2).
    listens: ClassVar[bool] = False
    # Robots that do not poll push their belief to both neighbours when :meth:`wants_push`.
    pushes: ClassVar[bool] = False
    # Floats a reply carries beyond position and belief (:meth:`reply_content`).
    reply_fields: ClassVar[int] = 0

    def check(self, scenario: Scenario) -> None:
        """Raise :class:`StrategyError` when ``scenario`` does not suit the strategy."""
        mode = scenario.estimation.mode
        if self.estimation is not None and mode != self.estimation:
            raise StrategyError(f"the {self.name} strategy needs estimation.mode = '{self.estimation}' "
                                f"(it is '{mode}'); give --estimation {self.estimation}")

    def controller(self, region: ConvexRegion, params: ControlParams, own_position: ArrayLike) -> Controller:
        """A new memory for robots at ``own_position`` (metres, ``S + (2,)``)."""
        return MidpointController(region, params, own_position, rule=self.triggers)

    def triggers(self, controller: Any) -> Reasons:
        """For a step after the first: the :class:`~agents.laws.Trigger` mask of every robot, from
        its controller's view (``theta``, ``m_minus``, ``m_plus`` radians, ages in steps). The
        default is the self-triggered rule (T1-T3)."""
        return self_triggered_rule(controller)

    def reply_content(self, controller: Any) -> FloatArray:
        """The ``reply_fields`` floats a reply of each robot carries (``S + (reply_fields,)``), read
        after the robot observed the requested step."""
        return np.zeros((*np.shape(controller.theta), self.reply_fields))

    def receive(self, controller: Any, predecessor: Received, successor: Received) -> None:
        """Take the replies of a step into the controller (by default positions and ages)."""
        controller.receive(predecessor.position, successor.position, predecessor.fresh, successor.fresh,
                           predecessor.age, successor.age)

    def wants_push(self, mean: FloatArray, last_mean: FloatArray, last_covariance: FloatArray,
                   params: EstimationParams) -> NDArray[np.bool_]:
        """Whether a robot that does not poll pushes its belief (``mean`` metres ``S + (2,)``) to
        both neighbours, given the belief it last told them (``last_mean``, ``last_covariance``
        m^2, ``S + (2, 2)``); only for strategies with :attr:`pushes`."""
        return np.zeros(np.shape(mean)[:-1], dtype=bool)

    def hear(self, estimator: Estimator, positions: ArrayLike, ranges: ArrayLike,
             beliefs: list[tuple[FloatArray, FloatArray]]) -> None:
        """One robot's estimation step (its ``ranges`` measured from ``positions``) given the beliefs
        ``(mean, covariance)`` its neighbours told it in the previous step (predecessor first; maybe
        none): by default they are fused by covariance intersection after the prediction, before
        the update (:meth:`agents.estimation.Estimator.measure`). Only for :attr:`listens`."""
        estimator.measure(positions, ranges, beliefs)


class StrategyError(ValueError):
    """A strategy name or file that cannot be used, or a scenario it does not suit; the message
    says why and how to fix it."""


class Constant(Strategy):
    """Poll both neighbours every step (the paper's constant strategy)."""

    name = "constant"
    summary = "poll both neighbours every step"

    def triggers(self, controller: Any) -> Reasons:
        return np.full(np.shape(controller.theta), int(Trigger.SCHEDULE), dtype=np.int64)


class SelfTriggered(Strategy):
    """Poll when the neighbours' motion prediction sets say the memory is no longer safe (T1-T3):
    Zhou and Tokekar, *Active Target Tracking with Self-Triggered Communications in Multi-Robot Teams*."""

    name = "self"
    summary = "the paper's self-triggered rule (T1-T3)"


# Registered strategies: name -> "module:class" (imported when first used).
REGISTRY: dict[str, str] = {
    "constant": "ringtrack.agents.strategy:Constant",
    "self": "ringtrack.agents.strategy:SelfTriggered",
    "belief": "ringtrack.agents.belief:SharedBelief",
    "plan": "ringtrack.agents.plan:PlanStrategy",
}


def strategy_for(name_or_path: str) -> Strategy:
    """The strategy registered as ``name_or_path``, or the one a Python file at that path defines
    (exactly one subclass of :class:`Strategy`); :class:`StrategyError` otherwise."""
    return _strategy(name_or_path)


@cache
def _strategy(name_or_path: str) -> Strategy:
    if name_or_path in REGISTRY:
        module, _, attribute = REGISTRY[name_or_path].partition(":")
        return getattr(importlib.import_module(module), attribute)()
    path = Path(name_or_path)
    fix = f"give one of {', '.join(sorted(REGISTRY))} or the path of a .py file that defines a Strategy"
    if path.suffix != ".py":
        raise StrategyError(f"'{name_or_path}' is not a registered strategy nor a Python file; {fix}")
    if not path.is_file():
        raise StrategyError(f"{name_or_path}: no such file; {fix}")
    return _load_file(path.resolve())


def _load_file(path: Path) -> Strategy:
    """Import a strategy file as a module of its own and instantiate its one Strategy subclass."""
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(f"ringtrack_strategy_{digest}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as error:  # a researcher's file: report any failure in one line
        raise StrategyError(f"{path}: the strategy file failed to load ({type(error).__name__}: {error}); "
                            "fix the file") from None
    found = [value for value in vars(module).values() if isinstance(value, type) and issubclass(value, Strategy)
             and value.__module__ == module.__name__]
    if len(found) != 1:
        raise StrategyError(f"{path}: defines {len(found)} subclasses of ringtrack.agents.strategy.Strategy; "
                            "define exactly one")
    strategy = found[0]()
    if not strategy.name or strategy.name in REGISTRY:
        raise StrategyError(f"{path}: {found[0].__name__}.name is {strategy.name!r}; give it a name of its own "
                            f"(not one of {', '.join(sorted(REGISTRY))})")
    return strategy


def check_strategy(scenario: Scenario) -> Strategy:
    """The scenario's strategy, checked against the scenario (:class:`StrategyError` if unusable)."""
    strategy = strategy_for(scenario.control.strategy)
    strategy.check(scenario)
    return strategy
