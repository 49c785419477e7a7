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

A strategy owns its knowledge: its parameters (:attr:`~Strategy.parameters`, each a
:class:`StrategyParameter` with type, default, units, help and bounds, set in a scenario's
``[strategy]`` section and checked here when the strategy is built: an instance holds them as
attributes, resolved once), which Cerr its runs report (:attr:`~Strategy.cerr`), how tables name it
(:attr:`~Strategy.label`) and which scenarios it suits (:meth:`~Strategy.check`). Nothing outside a
strategy's own module compares against its name.

Strategies are found by name (:data:`REGISTRY`) or loaded from a Python file defining exactly one
subclass of :class:`Strategy` (:func:`strategy_for`); :func:`describe_strategies` tells what each
declares (``ringtrack strategies``); docs/strategies.md walks through writing one.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ringtrack.agents.controller import CentreUncertainty, MidpointController, self_triggered_rule
from ringtrack.agents.laws import Mask, Trigger
from ringtrack.world.geometry import ConvexRegion, FloatArray
from ringtrack.world.metrics import CerrSource
from ringtrack.world.params import ControlParams, EstimationParams, Mode, StrategyChoice, StrategyValue

if TYPE_CHECKING:
    from ringtrack.agents.estimation import Estimators, Told
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
                reach: tuple[ArrayLike, ArrayLike] = (True, True),
                uncertainty: CentreUncertainty | None = None) -> Reasons: ...

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


ParameterType = type[bool] | type[int] | type[float] | type[str]
PARAMETER_TYPES: dict[type, str] = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


@dataclass(frozen=True)
class StrategyParameter:
    """One parameter a strategy declares (:attr:`Strategy.parameters`), set in a scenario's
    ``[strategy]`` section as ``name = value``.

    ``type`` is ``bool``, ``int``, ``float`` (an integer is taken as a float) or ``str``; ``default``
    the value when the scenario gives none; ``units`` how the value is measured ("steps", "m",
    "rad", ...; "" for a dimensionless one); ``help`` one line on what it does; bounds on a number
    (``gt`` / ``ge`` below, ``le`` above) and the allowed ``choices`` of a string (empty: any).
    """

    name: str
    type: ParameterType
    default: StrategyValue
    units: str = ""
    help: str = ""
    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.type not in PARAMETER_TYPES:
            raise StrategyError(f"parameter {self.name!r} has type {self.type!r}; declare bool, int, float or str")
        if not self.name.isidentifier() or self.name.startswith("_") or self.name == "name":
            raise StrategyError(f"parameter name {self.name!r}; declare an identifier other than 'name' "
                                "that does not start with '_'")
        if (self.gt, self.ge, self.le) != (None, None, None) and self.type not in (int, float):
            raise StrategyError(f"parameter {self.name!r}: bounds need a number type; declare int or float")
        if self.choices and self.type is not str:
            raise StrategyError(f"parameter {self.name!r}: choices need type str; declare str")
        problem = self.problem(self.default)
        if problem is not None:
            raise StrategyError(f"parameter {self.name!r}: its default {problem}; declare a default that is "
                                f"{self.expects}")

    @property
    def expects(self) -> str:
        """What a value must be, in words: "a number > 0", "an integer >= 0 and <= 10000", ..."""
        if self.choices:
            return "one of " + ", ".join(json.dumps(choice) for choice in self.choices)
        bounds = [f"{sign} {_show(bound)}" for sign, bound in ((">", self.gt), (">=", self.ge), ("<=", self.le))
                  if bound is not None]
        return " ".join([PARAMETER_TYPES[self.type], " and ".join(bounds)]).strip()

    def problem(self, value: Any) -> str | None:
        """None when ``value`` suits the declaration; else what is wrong with it ("must be > 0 (it
        is -1)")."""
        kind = self.type
        if kind is float:
            fits = isinstance(value, int | float) and not isinstance(value, bool)
        elif kind is int:
            fits = isinstance(value, int) and not isinstance(value, bool)
        else:
            fits = isinstance(value, kind)
        it_is = f"(it is {_show(value)})"
        if not fits:
            return f"must be {PARAMETER_TYPES[kind]} {it_is}"
        if kind is float and not math.isfinite(value):
            return f"must be a finite number {it_is}"
        for sign, bound, holds in ((">", self.gt, lambda b: value > b), (">=", self.ge, lambda b: value >= b),
                                   ("<=", self.le, lambda b: value <= b)):
            if bound is not None and not holds(bound):
                return f"must be {sign} {_show(bound)} {it_is}"
        if self.choices and value not in self.choices:
            return f"must be {self.expects} {it_is}"
        return None

    def resolve(self, value: Any, where: str = "strategy") -> StrategyValue:
        """``value`` checked and in the declared type (:class:`StrategyError` naming the key,
        ``strategy.NAME`` in the section ``where``, and the fix otherwise)."""
        problem = self.problem(value)
        if problem is not None:
            raise StrategyError(f"{where}.{self.name} {problem}; give {self.expects} "
                                f"(default {_show(self.default)})", key=self.name)
        return float(value) if self.type is float else value


def _show(value: Any) -> str:
    """A value as a scenario file writes it (TOML): true, 2.5, "text"."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


class Strategy:
    """A communication strategy. Subclasses set :attr:`name` (and :attr:`summary`) and override
    what they change; every method is vectorised over the leading shape of its arrays.

    A strategy is built from the values of its declared :attr:`parameters` (a scenario's
    ``[strategy]`` table, :func:`strategy_for`): each is checked against its declaration, a
    missing one takes its default, and the strategy holds it as an attribute of that name (declare
    its type on the class too, e.g. ``push_gate: float``), so per-step code reads a plain attribute.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    # How tables, figures and the dashboard name the strategy ("self-triggered"); "" means ``name``.
    label: ClassVar[str] = ""
    # The parameters a scenario's [strategy] section sets (each an attribute of a built strategy).
    parameters: ClassVar[tuple[StrategyParameter, ...]] = ()
    # Which Cerr is the paper's Cerr of a run (convergence, Ctime): "memory" (the robots' guaranteed
    # offsets, for every strategy whose memory says something) or "true" (true positions).
    cerr: ClassVar[CerrSource] = "memory"
    # The estimation mode the strategy needs (None: any); checked by :meth:`check`.
    estimation: ClassVar[Mode | None] = None
    # Requests carry the requester's belief and neighbours fuse the beliefs told them (step 2).
    listens: ClassVar[bool] = False
    # Robots that do not poll push their belief to both neighbours when :meth:`wants_push`.
    pushes: ClassVar[bool] = False
    # Requests and replies carry the ranges their sender holds (:mod:`agents.relay`).
    relays: ClassVar[bool] = False
    # The trigger rule reads how well each robot knows the centre (``controller.uncertainty``, a
    # :class:`agents.controller.CentreUncertainty`), which engine and robot processes then provide.
    reads_uncertainty: ClassVar[bool] = False
    # Floats a reply carries beyond position and belief (:meth:`reply_content`).
    reply_fields: ClassVar[int] = 0

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        names = [parameter.name for parameter in cls.parameters]
        taken = [name for name in names if name in vars(Strategy) or names.count(name) > 1]
        if taken:
            raise StrategyError(f"{cls.__name__} declares the parameter {taken[0]!r} twice or over a member of "
                                "Strategy; give it another name")

    def __init__(self, values: Mapping[str, StrategyValue] | None = None,
                 where: Mapping[str, str] | None = None) -> None:
        """Build the strategy from the values of its parameters (defaults for those not given);
        :class:`StrategyError` names an unknown key or a bad value, ``strategy.KEY``, and the fix.
        ``where`` tells the section each key came from (default "strategy"; "strategy.NAME" for a
        ``[strategy.NAME]`` table)."""
        given = dict(values or {})
        place = where or {}
        declared = {parameter.name: parameter for parameter in self.parameters}
        for key in given:
            if key not in declared:
                known = (f"give one of {', '.join(declared)}" if declared
                         else "it has no parameters; remove the key")
                raise StrategyError(f"{place.get(key, 'strategy')}.{key}: the {self.name} strategy has no parameter "
                                    f"{key!r}; {known}", key=key)
        self.values: dict[str, StrategyValue] = {
            name: parameter.resolve(given[name], place.get(name, "strategy")) if name in given else parameter.default
            for name, parameter in declared.items()
        }
        for name, value in self.values.items():
            setattr(self, name, value)

    @classmethod
    def display_label(cls) -> str:
        """How tables and figures name the strategy: its :attr:`label`, else its :attr:`name`."""
        return cls.label or cls.name

    @classmethod
    def description(cls) -> str:
        """One line on what the strategy does: its :attr:`summary`, else its docstring's first line."""
        lines = (cls.__doc__ or "").strip().splitlines()
        return cls.summary or (lines[0] if lines else "")

    def check(self, scenario: Scenario) -> None:
        """Raise :class:`StrategyError` when ``scenario`` does not suit the strategy (by default: the
        estimation mode it needs); a strategy with more needs extends it."""
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
        m^2, ``S + (2, 2)``) and the team's estimation parameters; only for strategies with
        :attr:`pushes`."""
        return np.zeros(np.shape(mean)[:-1], dtype=bool)

    def hear(self, estimators: Estimators, positions: ArrayLike, ranges: ArrayLike, told: Told) -> None:
        """The estimation step of a batch of robots (their ``ranges`` (B, m) measured from
        ``positions`` (B, m, 2), metres) given the beliefs their neighbours ``told`` them in the
        previous step: by default they are fused by covariance intersection after the prediction,
        before the update (:meth:`agents.estimation.Estimators.measure`). A robot process is a batch
        of one. Only for :attr:`listens`."""
        estimators.measure(positions, ranges, told)


class StrategyError(ValueError):
    """A strategy name or file that cannot be used, a scenario it does not suit, or a bad value of
    one of its parameters; the message says why and how to fix it. ``key`` is the ``[strategy]``
    key at fault: "name" for the strategy itself (the message then does not name it), else the
    parameter's key (the message then starts ``strategy.KEY``)."""

    def __init__(self, message: str, key: str = "name") -> None:
        super().__init__(message)
        self.key = key


class Constant(Strategy):
    """Poll both neighbours every step (the paper's constant strategy)."""

    name = "constant"
    summary = "poll both neighbours every step"
    cerr = "true"  # its memory is always a step old: the paper takes Cerr from the true positions

    def triggers(self, controller: Any) -> Reasons:
        return np.full(np.shape(controller.theta), int(Trigger.SCHEDULE), dtype=np.int64)


class SelfTriggered(Strategy):
    """Poll when the neighbours' motion prediction sets say the memory is no longer safe (T1-T3):
    Zhou and Tokekar, *Active Target Tracking with Self-Triggered Communications in Multi-Robot Teams*."""

    name = "self"
    summary = "the paper's self-triggered rule (T1-T3)"
    label = "self-triggered"


# Registered strategies: name -> "module:class" (imported when first used).
REGISTRY: dict[str, str] = {
    "constant": "ringtrack.agents.strategy:Constant",
    "self": "ringtrack.agents.strategy:SelfTriggered",
    "belief": "ringtrack.agents.belief:SharedBelief",
    "plan": "ringtrack.agents.plan:PlanStrategy",
    "relay": "ringtrack.agents.relay_strategy:RelayedRanges",
}


def strategy_for(choice: str | StrategyChoice) -> Strategy:
    """The strategy a scenario's ``[strategy]`` section chooses (:class:`StrategyChoice`; a plain
    string: that strategy with its defaults), built with its parameters checked: the strategy
    registered under the name, or the one a Python file at that path defines (exactly one subclass
    of :class:`Strategy`); :class:`StrategyError` otherwise. Its parameters are the section's plain
    keys over those of its own ``[strategy.NAME]`` table (``NAME`` its :attr:`Strategy.name`)."""
    if isinstance(choice, str):
        choice = StrategyChoice(choice)
    return _strategy(choice)


@cache
def _strategy(choice: StrategyChoice) -> Strategy:
    cls = strategy_class(choice.name)
    own = choice.table(cls.name)
    values = {**own, **dict(choice.values)}
    where = {key: f"strategy.{cls.name}" for key in own} | {key: "strategy" for key, _ in choice.values}
    return cls(values, where)


def strategy_class(name_or_path: str) -> type[Strategy]:
    """The class of the strategy registered as ``name_or_path`` or defined by the Python file at
    that path (imported once per content of the file, so that a process that lives on, such as a
    cluster's worker, runs a file edited since as it is now); :class:`StrategyError` otherwise."""
    if name_or_path in REGISTRY:
        module, _, attribute = REGISTRY[name_or_path].partition(":")
        found: type[Strategy] = getattr(importlib.import_module(module), attribute)
        return found
    path = Path(name_or_path)
    fix = f"give one of {', '.join(sorted(REGISTRY))} or the path of a .py file that defines a Strategy"
    if path.suffix != ".py":
        raise StrategyError(f"'{name_or_path}' is not a registered strategy nor a Python file; {fix}")
    if not path.is_file():
        raise StrategyError(f"{name_or_path}: no such file; {fix}")
    return _load_file(path.resolve(), path.read_bytes())


@cache
def _load_file(path: Path, source: bytes) -> type[Strategy]:
    """Import a strategy file (its ``source`` as read from ``path``) as a module of its own and find
    its one Strategy subclass."""
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(f"ringtrack_strategy_{digest}", path)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    try:
        exec(compile(source, path, "exec"), vars(module))  # the bytes read, not the file as it may be by now
    except Exception as error:  # a researcher's file: report any failure in one line
        raise StrategyError(f"{path}: the strategy file failed to load ({type(error).__name__}: {error}); "
                            "fix the file") from None
    found = [value for value in vars(module).values() if isinstance(value, type) and issubclass(value, Strategy)
             and value.__module__ == module.__name__]
    if len(found) != 1:
        raise StrategyError(f"{path}: defines {len(found)} subclasses of ringtrack.agents.strategy.Strategy; "
                            "define exactly one")
    strategy = found[0]
    if not strategy.name or strategy.name in REGISTRY:
        raise StrategyError(f"{path}: {strategy.__name__}.name is {strategy.name!r}; give it a name of its own "
                            f"(not one of {', '.join(sorted(REGISTRY))})")
    return strategy


def check_strategy(scenario: Scenario) -> Strategy:
    """The scenario's strategy built from its ``[strategy]`` section and checked against the
    scenario (:class:`StrategyError` if unusable)."""
    strategy = strategy_for(scenario.strategy)
    strategy.check(scenario)
    return strategy


@dataclass(frozen=True)
class StrategyDescription:
    """What a strategy declares, for people (``ringtrack strategies``): its ``name``, ``label``
    (tables and figures), one line on what it does (``description``), the estimation mode it needs
    (None: any), which Cerr its runs report and its parameters."""

    name: str
    label: str
    description: str
    estimation: Mode | None
    cerr: CerrSource
    parameters: tuple[StrategyParameter, ...]

    def to_json(self) -> dict[str, Any]:
        """The description as JSON-ready builtins (a parameter's type by its name: "float", ...)."""
        return {
            "name": self.name, "label": self.label, "description": self.description,
            "estimation": self.estimation, "cerr": self.cerr,
            "parameters": [{"name": p.name, "type": p.type.__name__, "default": p.default, "units": p.units,
                            "help": p.help, "expects": p.expects} for p in self.parameters],
        }


def describe_strategy(name_or_path: str) -> StrategyDescription:
    """What the strategy registered as ``name_or_path`` (or defined by that file) declares."""
    cls = strategy_class(name_or_path)
    return StrategyDescription(cls.name, cls.display_label(), cls.description(), cls.estimation, cls.cerr,
                               cls.parameters)


def describe_strategies(extra: tuple[str, ...] = ()) -> list[StrategyDescription]:
    """Every registered strategy, in :data:`REGISTRY` order, then those of the files ``extra``."""
    return [describe_strategy(name) for name in (*REGISTRY, *extra)]
