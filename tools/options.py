"""Command-line flags shared by the commands that load a scenario."""

from __future__ import annotations

import argparse

from world.scenario import Scenario, load_scenario

DEFAULT_SCENARIO = "paper-stationary"


def add_scenario_arguments(parser: argparse.ArgumentParser, steps_help: str) -> None:
    """``[SCENARIO] --strategy --law --robots --seed --steps --sigma-deg --estimation``."""
    parser.add_argument(
        "scenario",
        nargs="?",
        default=DEFAULT_SCENARIO,
        help=f"a TOML file or a shipped scenario name (default: {DEFAULT_SCENARIO})",
    )
    parser.add_argument("--strategy", choices=["self", "constant"], help="communication strategy")
    parser.add_argument("--law", choices=["prop", "deadbeat"], help="fresh-information law")
    parser.add_argument(
        "--robots",
        type=int,
        help="team size; explicit start angles of another size are replaced by a seeded random start",
    )
    parser.add_argument("--seed", type=int, help="random seed (starts, noise, faults)")
    parser.add_argument("--steps", type=int, help=steps_help)
    parser.add_argument("--sigma-deg", type=float, help="trigger tolerance sigma in degrees")
    parser.add_argument("--estimation", choices=["known", "centralized", "decentralized"],
                        help="how the robots estimate the target")
    parser.add_argument("--drop", type=float, metavar="P", help="drop a share P of robot-to-robot messages")
    parser.add_argument("--duplicate", type=float, metavar="P", help="duplicate a share P of them")
    parser.add_argument("--communication-range", type=float, metavar="M", help="r_c in metres")


def scenario_from_arguments(args: argparse.Namespace) -> Scenario:
    """Load ``args.scenario`` with the flags applied (``--steps`` sets ``max_steps``)."""
    return load_scenario(
        args.scenario,
        strategy=args.strategy,
        law=args.law,
        robots=args.robots,
        seed=args.seed,
        max_steps=args.steps,
        sigma_deg=args.sigma_deg,
        estimation=args.estimation,
        drop=args.drop,
        duplicate=args.duplicate,
        communication_range=args.communication_range,
    )
