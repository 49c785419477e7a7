"""``ringtrack experiment gates``: the belief strategy's trade-off between talk and tracking over its
push gate g, against the centralized self-triggered team on the same random starts."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ringtrack.agents import engine
from ringtrack.tools.console import err, out, write_json
from ringtrack.tools.options import FIGURE_SUFFIXES, JSON_FILE, at_least, output_path
from ringtrack.world.metrics import settled_mean
from ringtrack.world.scenario import Scenario, apply_overrides, load_scenario, resolve


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
    parser.add_argument("--settle", type=at_least(0), default=300, help="means leave out the first steps (300)")
    parser.add_argument("--json", type=JSON_FILE, metavar="PATH", help="write the points")
    parser.add_argument("--plot", type=output_path(FIGURE_SUFFIXES), metavar="PNG", help="draw the trade-off")
    parser.set_defaults(handler=run_gates)


def gate_list(text: str) -> list[float]:
    try:
        gates = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        gates = []
    if not gates or min(gates) <= 0:
        raise argparse.ArgumentTypeError(f"--gates {text!r}: give positive numbers like 1,1.5,2,3,4")
    return gates


def with_gate(scenario: Scenario, gate: float) -> Scenario:
    return resolve(apply_overrides(scenario.spec, strategy_parameters={"belief": {"push_gate": gate}}), scenario.name)


def point(history: engine.History, settle: int) -> dict[str, float | None]:
    """Terr (metres), Cerr (degrees, true) and robot-to-robot messages per robot-step, settled means."""
    robots = history.angles.shape[2]
    messages = settled_mean(history.sent.sum(axis=-1), settle)
    return {"terr_mean": settled_mean(history.terr, settle), "cerr_mean_deg": settled_mean(history.cerr_true, settle),
            "robot_messages_per_robot_step": None if messages is None else messages / robots}


def gates_experiment(base: str, gates: list[float], trials: int, settle: int) -> dict:
    seeds = list(range(trials))
    started = time.perf_counter()
    central = engine.run(load_scenario(base, strategy="self", estimation="centralized"), seeds, record_positions=False)
    points = []
    for gate in gates:
        err.print(f"gates: g = {gate:g}", highlight=False)
        scenario = with_gate(load_scenario(base, strategy="belief", estimation="decentralized"), gate)
        points.append({"gate": gate, **point(engine.run(scenario, seeds, record_positions=False), settle)})
    return {"experiment": "gates", "scenario": base, "trials": trials, "settle": settle,
            "centralized": point(central, settle), "points": points, "wall_s": time.perf_counter() - started}


def run_gates(args: argparse.Namespace) -> int:
    result = gates_experiment(args.scenario, args.gates, args.trials, args.settle)
    central = result["centralized"]
    out.print(f"self + centralized: Terr {central['terr_mean']:.3f} m, Cerr {central['cerr_mean_deg']:.1f} deg, "
              f"{central['robot_messages_per_robot_step']:.3f} msg/robot-step", highlight=False)
    for entry in result["points"]:
        out.print(f"belief g = {entry['gate']:g}: Terr {entry['terr_mean']:.3f} m "
                  f"({entry['terr_mean'] / central['terr_mean']:.2f} x), Cerr {entry['cerr_mean_deg']:.1f} deg, "
                  f"{entry['robot_messages_per_robot_step']:.3f} msg/robot-step", highlight=False)
    if args.json:
        write_json(args.json, result)
    if args.plot:
        plot_gates(result, args.plot)
    return 0


def plot_gates(result: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6, 4.2), layout="constrained")
    points = result["points"]
    xs = [entry["robot_messages_per_robot_step"] for entry in points]
    ys = [entry["terr_mean"] for entry in points]
    axis.plot(xs, ys, "o-", color="tab:red", label="belief (decentralized)")
    for entry, x, y in zip(points, xs, ys, strict=True):
        axis.annotate(f"g = {entry['gate']:g}", (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    central = result["centralized"]
    axis.axhline(central["terr_mean"], color="tab:orange", linestyle="--", label="self, centralized EKF")
    axis.set_xlabel("robot-to-robot messages per robot-step (constant: 4)")
    axis.set_ylabel("Terr (m)")
    axis.set_title(f"{result['scenario']}: {result['trials']} trials, means from step {result['settle']}", fontsize=10)
    axis.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
