"""``ringtrack experiment gates``: the belief strategy's push gate against messages and Terr."""

from __future__ import annotations

import argparse

from ringtrack.tools.cli.options import (
    add_output_arguments,
    add_study_arguments,
    at_least,
    execution_of,
    write_study,
)
from ringtrack.tools.output.console import out
from ringtrack.tools.studies.gates import GATED, REFERENCE, gates_experiment, plot_gates


def register(kinds: argparse._SubParsersAction) -> None:
    parser = kinds.add_parser(
        "gates",
        help="belief strategy: robot-to-robot messages per robot-step against Terr over the push gate g",
        description="Run the belief strategy (decentralized) for each push gate g and the self-triggered "
        "strategy with a centralized EKF on the same seeded starts; means once the first --settle steps "
        "are left out.",
    )
    parser.add_argument("scenario", nargs="?", default="authors-moving", help="base scenario (a moving target)")
    parser.add_argument("--gates", type=gate_list, default=[1.0, 1.5, 2.0, 3.0, 4.0], help="gates g, e.g. 1,2,4")
    parser.add_argument("--trials", type=at_least(1), default=5, help="random starts (default 5)")
    parser.add_argument("--steps", type=at_least(1), help="steps per run (default: control.max_steps)")
    parser.add_argument("--settle", type=at_least(0), default=300, help="means leave out the first steps (300)")
    add_output_arguments(parser, json="write the points", plot="draw the trade-off")
    add_study_arguments(parser)
    parser.set_defaults(handler=run_gates)


def gate_list(text: str) -> list[float]:
    try:
        gates = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        gates = []
    if not gates or min(gates) <= 0:
        raise argparse.ArgumentTypeError(f"--gates {text!r}: give positive numbers like 1,1.5,2,3,4")
    return gates


def run_gates(args: argparse.Namespace) -> int:
    result = gates_experiment(args.scenario, args.gates, args.trials, args.settle, args.steps,
                              execution_of(args, args.json))
    central = result.centralized
    reference, mode = REFERENCE
    out.print(f"{reference} + {mode}: Terr {central.terr_mean:.3f} m, Cerr {central.cerr_mean_deg:.1f} deg, "
              f"{central.robot_messages_per_robot_step:.3f} msg/robot-step", highlight=False)
    for entry in result.points:
        ratio = entry.terr_mean / central.terr_mean  # type: ignore[operator]  # settled means of settle < steps
        out.print(f"{GATED} g = {entry.gate:g}: Terr {entry.terr_mean:.3f} m "
                  f"({ratio:.2f} x), Cerr {entry.cerr_mean_deg:.1f} deg, "
                  f"{entry.robot_messages_per_robot_step:.3f} msg/robot-step", highlight=False)
    write_study(args, result, plot_gates)
    return 0
