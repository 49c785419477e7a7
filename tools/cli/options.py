"""Command-line flags shared by the commands: scenario overrides and checked number types."""

from __future__ import annotations

import argparse
import contextlib
import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TypeVar

import msgspec

from ringtrack.agents.strategy import (
    REGISTRY,
    StrategyError,
    StrategyParameter,
    check_strategy,
    strategy_class,
)
from ringtrack.tools.output.files import unwritable, write_csv, write_json
from ringtrack.tools.studies.cluster import CLUSTER_EXTRA
from ringtrack.tools.studies.journal import journal_path
from ringtrack.tools.studies.study import BATCH, Execution, available_cores
from ringtrack.world.params import StrategyValue
from ringtrack.world.scenario import OverrideError, Scenario, ScenarioError, load_scenario

DEFAULT_SCENARIO = "paper-stationary"
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")  # what matplotlib writes here
FLAGS = {"max_steps": "--steps"}  # command-line flags of scenario overrides not spelled like their name


def add_scenario_arguments(parser: argparse.ArgumentParser, steps_help: str) -> None:
    """``[SCENARIO] --strategy --law --robots --seed --steps --sigma-deg --estimation``."""
    parser.add_argument(
        "scenario",
        nargs="?",
        default=DEFAULT_SCENARIO,
        help=f"a TOML file or a shipped scenario name (default: {DEFAULT_SCENARIO})",
    )
    parser.add_argument("--strategy", metavar="NAME|FILE.py",
                        help=f"communication strategy: {', '.join(sorted(REGISTRY))}, or a Python file defining one "
                        "(docs/strategies.md)")
    parser.add_argument("--law", choices=["prop", "deadbeat"], help="fresh-information law")
    add_strategy_parameter_arguments(parser)
    parser.add_argument(
        "--robots",
        type=int,
        help="team size; explicit start angles of another size are replaced by a seeded random start",
    )
    parser.add_argument("--seed", type=at_least(0), help="random seed (starts, noise, faults)")
    parser.add_argument("--steps", type=at_least(1), help=steps_help)
    parser.add_argument("--sigma-deg", type=float, help="trigger tolerance sigma in degrees")
    parser.add_argument("--estimation", choices=["known", "centralized", "decentralized"],
                        help="how the robots estimate the target")
    parser.add_argument("--drop", type=float, metavar="P", help="drop a share P of robot-to-robot messages")
    parser.add_argument("--duplicate", type=float, metavar="P", help="duplicate a share P of them")
    parser.add_argument("--communication-range", type=float, metavar="M", help="r_c in metres")


# --steps of the commands that run a scenario (simulate, spawn, the world role): the default's words.
UNTIL_CONVERGED = ("a stationary target's run ends at convergence (at most control.max_steps), a moving target's "
                   "runs control.max_steps steps")


def stops_at_convergence(args: argparse.Namespace, scenario: Scenario) -> bool:
    """Whether a run ends at convergence: without ``--steps`` and for a stationary target only (a
    moving target is tracked for all of ``control.max_steps``: convergence says nothing of Terr)."""
    return args.steps is None and not scenario.moving


def add_from_step_argument(parser: argparse.ArgumentParser) -> None:
    """``--from-step S``: a moving target's Cerr and Terr means leave out the first S steps."""
    parser.add_argument("--from-step", type=at_least(0), default=300, metavar="S",
                        help="moving target: the summary's Cerr and Terr means leave out the first S steps "
                        "(default 300, as experiment moving --settle)")


@contextlib.contextmanager
def overrides_named_by_flag() -> Iterator[None]:
    """Report a scenario override's bad value (:class:`OverrideError`) by the flag that gave it, e.g.
    ``--drop 1.5 (faults.drop): expected a probability ...``."""
    try:
        yield
    except OverrideError as error:
        raise ScenarioError(f"{flag(error.name)} {error.value} ({error.path}){error.problem}") from None


def scenario_from_arguments(args: argparse.Namespace) -> Scenario:
    """Load ``args.scenario`` with the flags applied (``--steps`` sets ``max_steps``); a bad flag
    value is reported by its flag (:func:`overrides_named_by_flag`)."""
    with overrides_named_by_flag():
        scenario = load_scenario(
            args.scenario,
            strategy=strategy_argument(args.strategy),
            law=args.law,
            strategy_parameters=strategy_parameters(args),
            robots=args.robots,
            seed=args.seed,
            max_steps=args.steps,
            sigma_deg=args.sigma_deg,
            estimation=args.estimation,
            drop=args.drop,
            duplicate=args.duplicate,
            communication_range=args.communication_range,
        )
    checked_strategy(scenario, args.strategy, args.scenario)
    return scenario


def declared_parameters() -> dict[str, list[tuple[str, StrategyParameter]]]:
    """Every parameter the registered strategies declare, by name: the strategies that declare it
    (in :data:`REGISTRY` order) and their declarations."""
    declared: dict[str, list[tuple[str, StrategyParameter]]] = {}
    for name in REGISTRY:
        for parameter in strategy_class(name).parameters:
            declared.setdefault(parameter.name, []).append((name, parameter))
    return declared


def add_strategy_parameter_arguments(parser: argparse.ArgumentParser) -> None:
    """One flag per parameter a registered strategy declares (``plan_horizon``: ``--plan-horizon``),
    parsed and checked by its declaration; it sets the parameter of every strategy declaring it, in
    that strategy's ``[strategy.NAME]`` table, so it counts wherever that strategy runs."""
    for key, declared in declared_parameters().items():
        names = " and ".join(name for name, _ in declared)
        parameter = declared[0][1]
        units = f" ({parameter.units})" if parameter.units else ""
        parser.add_argument(f"--{key.replace('_', '-')}", dest=f"{PARAMETER_DEST}{key}",
                            type=parameter_value(f"--{key.replace('_', '-')}", parameter), metavar=key.upper(),
                            help=f"{names} strategy: {parameter.help}{units}; {parameter.expects}, default "
                            f"{parameter.default}")


PARAMETER_DEST = "strategy_parameter_"  # argparse destination prefix of the strategies' parameter flags
PARSERS: dict[type, Callable[[str], StrategyValue]] = {  # a flag's text as a declared parameter type
    bool: lambda text: {"true": True, "false": False}[text.lower()], int: int, float: float, str: str}


def parameter_value(flag: str, parameter: StrategyParameter) -> Callable[[str], StrategyValue]:
    """An argparse type for a strategy parameter's flag: the text as the declared type, within its
    bounds and choices, else one line naming the flag, the problem and what to give."""
    def parse(text: str) -> StrategyValue:
        try:
            value = PARSERS[parameter.type](text)
        except (KeyError, ValueError):
            raise argparse.ArgumentTypeError(f"{text!r} is not {parameter.expects}") from None
        problem = parameter.problem(value)
        if problem is not None:
            raise argparse.ArgumentTypeError(f"{text!r}: {problem}; give {parameter.expects}")
        return value

    parse.__name__ = flag
    return parse


def strategy_parameters(args: argparse.Namespace) -> dict[str, dict[str, StrategyValue]] | None:
    """What the strategies' parameter flags given set: ``{strategy: {parameter: value}}`` for every
    strategy declaring a parameter whose flag was given (None: no such flag)."""
    given: dict[str, dict[str, StrategyValue]] = {}
    for key, declared in declared_parameters().items():
        value = getattr(args, f"{PARAMETER_DEST}{key}", None)
        if value is not None:
            for name, _ in declared:
                given.setdefault(name, {})[key] = value
    return given or None


def strategy_argument(value: str | None) -> str | None:
    """A ``--strategy`` value as the scenario records it: a registered name as it is, a file's path
    made absolute (every process of a team reads it from the run folder's scenario)."""
    if value is None or value in REGISTRY or not value.endswith(".py"):
        return value
    return str(Path(value).resolve())


def checked_strategy(scenario: Scenario, flag_value: str | None, source: str) -> Scenario:
    """``scenario`` once its strategy loads, its ``[strategy]`` parameters check out and it suits
    the scenario; else a one-line :class:`ScenarioError` naming ``--strategy`` (when given) or the
    scenario's ``strategy.name``, or the scenario and the parameter's ``strategy.KEY``."""
    try:
        check_strategy(scenario)
    except StrategyError as error:
        if error.key != "name":  # the message names strategy.KEY
            where = source
        else:
            where = f"--strategy {flag_value}" if flag_value is not None else f"{source}: strategy.name"
        raise ScenarioError(f"{where}: {error}") from None
    return scenario


def flag(override: str) -> str:
    """The command-line flag of a scenario override (``max_steps`` -> ``--steps``, ``sigma_deg`` ->
    ``--sigma-deg``)."""
    return FLAGS.get(override, "--" + override.replace("_", "-"))


def positive(text: str) -> float:
    """An argparse type: a finite number > 0 (a rate, a speed factor, seconds)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive number; give e.g. 1 or 0.5")
    return value


TEAM_SIZES_EXAMPLE = "6, 3,6,10,20, 3-30 or 3-30:3"


def team_sizes(text: str) -> list[int]:
    """Team sizes from ``6``, a list ``3,6,10,20``, an inclusive range ``3-30``, a range with a step
    ``3-30:3``, or a list of these (``3,5-8``): each at least 3 and given once. A ``ValueError``
    says what is wrong (the flag's parser names the flag)."""
    sizes: list[int] = []
    for part in (part.strip() for part in text.split(",")):
        if not part:
            continue
        first, dash, rest = part.partition("-")
        last, colon, step = rest.partition(":")
        try:
            numbers = [int(first)] if not dash else [int(first), int(last), int(step) if colon else 1]
        except ValueError:
            raise ValueError(f"give team sizes like {TEAM_SIZES_EXAMPLE}") from None
        if dash and (numbers[1] < numbers[0] or numbers[2] < 1):
            raise ValueError(f"{part} is no range; give FIRST-LAST[:STEP], FIRST <= LAST, STEP >= 1, e.g. 3-30:3")
        sizes.extend(numbers if not dash else range(numbers[0], numbers[1] + 1, numbers[2]))
    if not sizes or min(sizes) < 3:
        raise ValueError("every team needs at least 3 robots")
    twice = next((size for index, size in enumerate(sizes) if size in sizes[:index]), None)
    if twice is not None:
        raise ValueError(f"{twice} is given twice; give each team size once")
    return sizes


def at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum`` (a count of steps, trials, rounds; a seed)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer; give one >= {minimum}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is below {minimum}; give an integer >= {minimum}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse


def output_path(suffixes: tuple[str, ...]) -> Callable[[str], Path]:
    """An argparse type: a file to write, ending in one of ``suffixes``; its folder is made and the
    file opened for writing before any work starts, so a long run never fails at its very end."""

    def parse(text: str) -> Path:
        path = Path(text)
        if not text or path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"{text!r}: give a file name ending in {' or '.join(suffixes)}")
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file name ending in {suffixes[0]}")
        problem = unwritable(path)
        if problem is not None:
            raise argparse.ArgumentTypeError(f"{text!r}: cannot write there ({problem}); give a writable path")
        return path

    return parse


def foxglove_address(text: str) -> tuple[str, int]:
    """An argparse type: ``[HOST:]PORT`` of a live Foxglove WebSocket server; HOST defaults to
    127.0.0.1 (this machine only: name a host, e.g. 0.0.0.0, to serve others), PORT 0 takes a free one."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: give [HOST:]PORT with a port 0-65535, e.g. 8765 or 0.0.0.0:8765")
    return host.strip("[]") or "127.0.0.1", number


SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")  # Dask's network protocols


def scheduler_address(text: str) -> str:
    """An argparse type: a Dask scheduler's ``[SCHEME://]HOST:PORT`` (SCHEME one of
    :data:`SCHEDULER_SCHEMES`, Dask's default tcp when left out; an IPv6 HOST in brackets)."""
    scheme, separator, location = text.rpartition("://")
    host, _, port = location.rpartition(":")
    if (separator and scheme not in SCHEDULER_SCHEMES) or not host.strip("[]") or not port.isdigit() \
            or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: give the scheduler's address as [{'|'.join(SCHEDULER_SCHEMES)}://]"
                                         "HOST:PORT with a port 1-65535, e.g. tcp://10.0.0.5:8786")
    return text


JSON_FILE = output_path((".json",))  # summaries and results
LOG_FILE = output_path((".jsonl",))  # run logs (JSON lines)
CSV_FILE = output_path((".csv",))  # tables of trials and summaries
MCAP_FILE = output_path((".mcap",))  # recordings for Foxglove


def add_study_arguments(parser: argparse.ArgumentParser, batch: int = BATCH) -> None:
    """``--workers --cluster --batch --resume --quiet``: how a study's tasks run (tools/studies/runner.py);
    ``batch`` is the study's own trials per task."""
    parser.add_argument("--workers", type=at_least(1), metavar="N",
                        help="run the tasks in N processes (default: every core this process may use)")
    parser.add_argument("--cluster", type=scheduler_address, metavar="ADDRESS",
                        help=f"run the tasks on the Dask scheduler at ADDRESS, e.g. tcp://host:8786 ({CLUSTER_EXTRA})")
    parser.add_argument("--batch", type=at_least(1), metavar="TRIALS",
                        help=f"trials per task, run as one engine batch (default {batch}); speed only: the results "
                        "are the same for any batch")
    parser.add_argument("--resume", action="store_true",
                        help="continue an interrupted study from its journal (PATH.journal.jsonl beside --json or "
                        "--csv), running only the tasks it lacks")
    parser.add_argument("--quiet", action="store_true", help="show no progress")


def execution_of(args: argparse.Namespace, *outputs: Path | None) -> Execution:
    """How the study the flags ask for runs; its journal lies beside the first of ``outputs`` given."""
    return Execution(workers=args.workers or available_cores(), cluster=args.cluster, batch=args.batch,
                     journal=journal_path(*outputs), resume=args.resume, quiet=args.quiet)


def add_output_arguments(parser: argparse.ArgumentParser, json: str, plot: str, csv: str | None = None) -> None:
    """An experiment command's ``--json PATH``, ``--csv PATH`` (when it has one) and ``--plot PNG``,
    each with its help; :func:`write_study` writes what they ask for."""
    parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help=json)
    if csv is not None:
        parser.add_argument("--csv", type=CSV_FILE, metavar="PATH", help=csv)
    parser.add_argument("--plot", type=output_path(FIGURE_SUFFIXES), metavar="PNG", help=plot)


StudyT = TypeVar("StudyT", bound=msgspec.Struct)


def write_study(args: argparse.Namespace, result: StudyT, plot: Callable[[StudyT, Path], None],
                rows: Sequence[msgspec.Struct] | None = None, columns: list[str] | None = None) -> None:
    """Write what an experiment command's ``--json`` (the whole ``result``), ``--csv`` (``rows`` as
    ``columns``; commands without the flag have no ``args.csv``) and ``--plot`` (drawn by ``plot``) ask for."""
    if args.json:
        write_json(args.json, result)
    if getattr(args, "csv", None) and rows is not None and columns is not None:
        write_csv(args.csv, rows, columns)
    if args.plot:
        plot(result, args.plot)
