"""``ringtrack bench record``: what ``spawn --record FILE.mcap`` and ``spawn --foxglove PORT`` cost a
lockstep team.

Runs the same lockstep team in turn without either, with ``--record`` and with ``--foxglove`` (a live
server on a free loopback port, no viewer connected), repeatedly, and reports the median steps per
second of each (the world's own count: stepping only), each one's cost and whether it is within the
budget (:data:`BUDGET`). A measurement to read, never a test's assertion.
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import Any

from ringtrack.tools.output.console import err
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario

BUDGET = 0.05  # a lockstep step with --record or --foxglove may cost this share more
VARIANTS = ("off", "record", "foxglove")


def record_cost(robots: int = 6, steps: int = 1000, repeat: int = 3, scenario: str = "authors-moving",
                runs: Path | None = None) -> dict[str, Any]:
    """Median lockstep steps per second of ``repeat`` runs of each of :data:`VARIANTS` (in turn, so
    a machine's drift hits them all), each variant's cost ``1 - variant / off`` and the MCAP's size."""
    team = load_scenario(scenario, robots=robots, max_steps=steps)
    speeds: dict[str, list[float]] = {variant: [] for variant in VARIANTS}
    sizes = []
    with tempfile.TemporaryDirectory(prefix="ringtrack-bench-record-") as scratch:
        folder = runs or Path(scratch)
        for attempt in range(repeat):
            for variant in VARIANTS:
                mcap = Path(scratch) / f"run-{attempt}.mcap" if variant == "record" else None
                live = ("127.0.0.1", 0) if variant == "foxglove" else None
                err.print(f"{robots} robots, {steps} lockstep steps, {variant} ({attempt + 1}/{repeat})",
                          highlight=False)
                result = spawn_team(TeamPlan(scenario=team, clock="lockstep", runs=folder, dashboard=False,
                                             quiet=True, record=mcap, foxglove=live))
                speeds[variant].append(result.steps_per_s or 0.0)
                if mcap is not None and mcap.exists():
                    sizes.append(mcap.stat().st_size)
    median = {variant: statistics.median(values) for variant, values in speeds.items()}
    cost = {variant: 1.0 - median[variant] / median["off"] if median["off"] else float("nan")
            for variant in VARIANTS[1:]}
    return {"benchmark": "record", "scenario": scenario, "robots": robots, "steps": steps, "repeat": repeat,
            "steps_per_s": median, "runs_steps_per_s": speeds, "cost": cost, "budget": BUDGET,
            "within_budget": {variant: value <= BUDGET for variant, value in cost.items()},
            "mcap_bytes_per_step": statistics.median(sizes) / steps if sizes else None}
