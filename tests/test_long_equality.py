"""Lockstep equals the engine bit for bit, at any length: one robot's process and the engine's
batched team call the same functions, whose rounding does not depend on the array shapes."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario


def test_the_boundary_map_of_a_batch_equals_that_of_each_robot_bit_for_bit() -> None:
    region = load_scenario("authors-moving").region
    rng = np.random.default_rng(1)
    centres = region.chebyshev_centre[0] + rng.normal(0.0, 0.3, (4, 6, 2))
    theta = rng.uniform(0.0, 2 * np.pi, (4, 6))
    batched = region.boundary_point(theta, centres)
    single = np.array([[region.boundary_point(theta[t, i], centres[t, i]) for i in range(6)] for t in range(4)])
    assert np.array_equal(batched, single)
    arcs = np.array([[region.arc_length(point) for point in row] for row in batched])
    assert np.array_equal(region.arc_length(batched), arcs)
    assert np.array_equal(region.heights(centres), np.array([[region.heights(c) for c in row] for row in centres]))


def lockstep_equals_engine_exactly(tmp_path: Path, steps: int, name: str, estimation: str,
                                   robots_per_process: int = 1) -> None:
    """The engine's run is computed in a thread while the team runs (the team's processes mostly
    wait on one another, so the two share the machine well)."""
    scenario = load_scenario(name, estimation=estimation, max_steps=steps)
    with ThreadPoolExecutor(1) as pool:
        future = pool.submit(engine.run, scenario, seeds=scenario.seed, steps=steps, record_positions=True)
        result = spawn_team(TeamPlan(scenario=scenario, runs=tmp_path, dashboard=False, quiet=True,
                            robots_per_process=robots_per_process))
        twin = future.result()
    assert result.exit_code == 0
    log = read_log(Path(result.log))
    assert len(log.steps) == steps
    assert log.header["seed"] == scenario.seed and log.scenario.to_toml() == scenario.to_toml()
    logged = history_from_log(log)
    assert np.array_equal(logged.positions, twin.positions)  # bit for bit, every robot, every step
    assert np.array_equal(logged.triggers, twin.triggers)
    assert np.array_equal(logged.estimates, twin.estimates)
    assert np.array_equal(logged.covariances, twin.covariances, equal_nan=True)


@pytest.mark.parametrize(("name", "estimation"), [("paper-stationary", "known"), ("authors-moving", "centralized"),
                                                   ("authors-moving", "decentralized")])
@pytest.mark.processes
def test_a_lockstep_run_equals_the_engine_bit_for_bit(tmp_path: Path, name: str, estimation: str) -> None:
    lockstep_equals_engine_exactly(tmp_path, 300, name, estimation)


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_a_lockstep_decentralized_run_of_20000_steps_equals_the_engine_bit_for_bit(tmp_path: Path) -> None:
    """The six robots share one process (each still its own Zenoh participant, polling its neighbours
    over the bus): half the CPU and wall time of six robot processes, the same messages and protocol."""
    lockstep_equals_engine_exactly(tmp_path, 20_000, "authors-moving", "decentralized", robots_per_process=6)
