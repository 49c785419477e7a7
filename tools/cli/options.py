"""Command-line flags shared by the commands: scenario overrides and checked number types."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from ringtrack.agents.strategy import REGISTRY, StrategyError, check_strategy
from ringtrack.tools.output.files import unwritable
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
    parser.add_argument("--plan-horizon", type=at_least(0), metavar="H",
                        help="plan strategy: the most steps ahead a reply's plan describes")
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


def add_from_step_argument(parser: argparse.ArgumentParser) -> None:
    """``--from-step S``: a moving target's Cerr and Terr means leave out the first S steps."""
    parser.add_argument("--from-step", type=at_least(0), default=300, metavar="S",
                        help="moving target: the summary's Cerr and Terr means leave out the first S steps "
                        "(default 300, as experiment moving --settle)")


def scenario_from_arguments(args: argparse.Namespace) -> Scenario:
    """Load ``args.scenario`` with the flags applied (``--steps`` sets ``max_steps``); a bad flag
    value is reported by its flag, e.g. ``--drop 1.5 (faults.drop): expected a probability ...``."""
    try:
        scenario = load_scenario(
            args.scenario,
            strategy=strategy_argument(args.strategy),
            law=args.law,
            strategy_parameters=plan_horizon(args),
            robots=args.robots,
            seed=args.seed,
            max_steps=args.steps,
            sigma_deg=args.sigma_deg,
            estimation=args.estimation,
            drop=args.drop,
            duplicate=args.duplicate,
            communication_range=args.communication_range,
        )
    except OverrideError as error:
        raise ScenarioError(f"{flag(error.name)} {error.value} ({error.path}){error.problem}") from None
    return checked_strategy(scenario, args.strategy, args.scenario)


def plan_horizon(args: argparse.Namespace) -> dict[str, dict[str, StrategyValue]] | None:
    """``--plan-horizon H`` as what it sets: ``[strategy.plan] plan_horizon``, the plan strategy's
    parameter wherever that strategy runs (and nothing where another does)."""
    return None if args.plan_horizon is None else {"plan": {"plan_horizon": args.plan_horizon}}


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


JSON_FILE = output_path((".json",))  # summaries and results
LOG_FILE = output_path((".jsonl",))  # run logs (JSON lines)
CSV_FILE = output_path((".csv",))  # tables of trials and summaries
