"""``ringtrack bench record``: what ``spawn --record FILE.mcap`` costs a lockstep team.

Runs the same lockstep team alternately without and with the monitor recording MCAP (the budget: a
step costs at most :data:`BUDGET` more), and reports the median steps per second of each, the cost
and whether it is within the budget. A measurement to read, never a test's assertion.
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

BUDGET = 0.05  # a lockstep step with --record may cost this share more


def record_cost(robots: int = 6, steps: int = 1000, repeat: int = 3, scenario: str = "authors-moving",
                runs: Path | None = None) -> dict[str, Any]:
    """Median lockstep steps per second of ``repeat`` runs without and ``repeat`` with ``--record``
    (alternating, so a machine's drift hits both), the cost ``1 - with / without`` and the MCAP size."""
    team = load_scenario(scenario, robots=robots, max_steps=steps)
    speeds: dict[bool, list[float]] = {False: [], True: []}
    sizes = []
    with tempfile.TemporaryDirectory(prefix="ringtrack-bench-record-") as scratch:
        folder = runs or Path(scratch)
        for attempt in range(repeat):
            for recording in (False, True):
                mcap = Path(scratch) / f"run-{attempt}.mcap" if recording else None
                err.print(f"{robots} robots, {steps} lockstep steps, --record {'on' if recording else 'off'} "
                          f"({attempt + 1}/{repeat})", highlight=False)
                result = spawn_team(TeamPlan(scenario=team, clock="lockstep", runs=folder, dashboard=False,
                                             quiet=True, record=mcap))
                speeds[recording].append(result.steps_per_s or 0.0)
                if mcap is not None and mcap.exists():
                    sizes.append(mcap.stat().st_size)
    without, with_record = statistics.median(speeds[False]), statistics.median(speeds[True])
    cost = 1.0 - with_record / without if without else float("nan")
    return {"benchmark": "record", "scenario": scenario, "robots": robots, "steps": steps, "repeat": repeat,
            "steps_per_s": without, "steps_per_s_with_record": with_record,
            "runs_steps_per_s": speeds[False], "runs_steps_per_s_with_record": speeds[True],
            "record_cost": cost, "budget": BUDGET, "within_budget": cost <= BUDGET,
            "mcap_bytes_per_step": statistics.median(sizes) / steps if sizes else None}
