"""``ringtrack experiment gates``: the belief strategy's trade-off between talk and tracking over its
push gate g, against the centralized self-triggered team on the same random starts."""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib.pyplot as plt

from ringtrack.agents import engine
from ringtrack.tools.output.console import err
from ringtrack.world.metrics import settled_mean
from ringtrack.world.scenario import Scenario, apply_overrides, load_scenario, resolve


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


def plot_gates(result: dict, path: Path) -> None:
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
