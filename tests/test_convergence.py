"""Convergence is claimed only on steps whose Cerr is known: missing offsets never count as zero error.

One rule decides convergence (:func:`world.metrics.converged` on :func:`world.metrics.strategy_cerr`, from
the Cerr the strategy names): the engine, the world process, histories read from run logs and the summaries built from them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents.summary import summarise
from ringtrack.bus.messages import SCHEMA, Command
from ringtrack.tools.runlog.log import history_from_log, read_log, write_engine_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.metrics import converged, convergence_step, memory_cerr, true_cerr
from ringtrack.world.state import WorldState
from tests.helpers import scenario

THRESHOLD_DEG = 0.6  # paper-stationary: 0.1 deg per robot, six robots


def test_a_missing_offset_leaves_cerr_unknown_and_never_converged() -> None:
    offsets = np.array([[0.0, 0.0, np.nan], [1e-4, 0.0, 0.0]])
    cerr = memory_cerr(offsets)
    assert np.isnan(cerr[0]) and cerr[1] == pytest.approx(np.rad2deg(1e-4))
    assert converged(cerr, THRESHOLD_DEG).tolist() == [False, True]
    assert convergence_step(cerr[:, None], THRESHOLD_DEG).tolist() == [2]
    # a robot out of the ring is no part of the sum; a live one without an offset is unknown
    assert memory_cerr(offsets[0], live=[True, True, False]) == 0.0
    assert np.isnan(memory_cerr(offsets[0], live=[False, True, True]))


def test_a_command_does_not_move_the_robots_before_the_step_ends() -> None:
    """The positions of a step are those its tick published until the world advances: taking the
    next goal (uncapped speed: the goal is reached in one step) must not move anyone at once, or the
    world would judge convergence on next step's positions (and a constant team end a step early)."""
    team = scenario(strategy="constant")
    assert team.v_max is None
    world = WorldState(team, seed=0, run=1, steps=10, cerr="true")
    world.advance()
    published = world.positions.copy()
    goal = team.region.boundary_point(1.0, team.region.chebyshev_centre[0])
    world.accept(Command(SCHEMA, 1, 2, 0, (float(goal[0]), float(goal[1])), 0, 0.0, (0, 0), (0.0, 0.0)))
    np.testing.assert_array_equal(world.positions, published)
    world.advance()
    np.testing.assert_allclose(world.positions[0], goal)


def test_the_world_does_not_converge_on_offsets_it_has_not_received() -> None:
    team = scenario()
    world = WorldState(team, seed=0, run=1, steps=10)
    assert not world.converged()  # nobody has reported: zero error is not known
    for robot in range(team.robots - 1):  # all but one report a perfect offset
        world.accept(Command(SCHEMA, 1, 1, robot, tuple(world.positions[robot]), 0, 0.0, (0, 0), (0.0, 0.0)))
    assert not world.converged()
    world.accept(Command(SCHEMA, 1, 1, team.robots - 1, tuple(world.positions[-1]), 0, 0.0, (0, 0), (0.0, 0.0)))
    assert world.converged()
    world.leave(2)  # a robot out of the ring is not waited for ...
    world.advance()
    for robot in (0, 1, 3, 4):
        world.accept(Command(SCHEMA, 1, 2, robot, tuple(world.positions[robot]), 0, 0.0, (0, 0), (0.0, 0.0)))
    assert not world.converged()  # ... but every live one is
    world.accept(Command(SCHEMA, 1, 1, 5, tuple(world.positions[5]), 0, 0.0, (0, 0), (0.0, 0.0)))
    assert not world.converged()  # an offset of an earlier step is not this step's
    world.accept(Command(SCHEMA, 1, 2, 5, tuple(world.positions[5]), 0, 0.0, (0, 0), (0.0, 0.0)))
    assert world.converged()


def test_a_log_with_missing_offsets_reports_no_convergence_there(tmp_path: Path) -> None:
    from ringtrack.agents import engine

    path = tmp_path / "log.jsonl"
    write_engine_log(path, engine.run(scenario(max_steps=5), steps=5))
    lines = path.read_text().splitlines()
    first = json.loads(lines[1])
    assert first["type"] == "step" and first["step"] == 1
    first["offset"] = [None] * 6  # step 1 as a racy realtime run logs it: no command arrived in time
    lines[1] = json.dumps(first)
    path.write_text("\n".join(lines) + "\n")
    history = history_from_log(read_log(path))
    assert np.isnan(history.cerr[0, 0]) and history.ctime[0] == 0
    assert summarise(history).converged is False


def racy_realtime_run(tmp_path: Path, strategy: str) -> tuple[dict, list[dict]]:
    """A realtime team at 20x (5 ms steps: step 1 is a race) that stops at convergence."""
    team = scenario(strategy=strategy, max_steps=1000)
    result = spawn_team(TeamPlan(scenario=team, clock="realtime", rate=20.0, runs=tmp_path, dashboard=False, until_converged=True,
                        quiet=True))
    assert result.exit_code == 0, result
    return result, read_log(Path(result.log)).steps


def assert_claims_only_known_convergence(result: dict, steps: list[dict]) -> list[int]:
    """Every step at which the run says it converged (the world's end, the log's Ctime) has a known
    Cerr below the threshold: self-triggered, every live robot's offset is in its record; constant,
    the true Cerr of its record. Returns those steps."""
    ended = result.outcome.steps if result.end_reason == "converged" else None
    claimed = [step for step in (result.outcome.ctime, ended) if step]
    for step in claimed:
        record = steps[step - 1]
        if result.outcome.strategy == "self":
            offsets = [record["offset"][robot] for robot in record["live"]]
            assert None not in offsets, (step, record["offset"])
            assert float(memory_cerr(offsets)) < THRESHOLD_DEG
        else:  # the constant strategy's Cerr is the true one
            assert float(true_cerr(np.array(record["positions"]), np.array(record["target"]))) < THRESHOLD_DEG
    return claimed


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(240)
def test_a_racy_realtime_self_triggered_run_never_claims_a_false_convergence(tmp_path: Path) -> None:
    result, steps = racy_realtime_run(tmp_path, "self")
    claimed = assert_claims_only_known_convergence(result, steps)
    # Wherever a live robot's offset did not reach the monitor, the logged run's Cerr is unknown.
    cerr = history_from_log(read_log(Path(result.log))).cerr[:, 0]
    unknown = [row for row, record in enumerate(steps)
               if any(record["offset"][robot] is None for robot in record["live"])]
    assert np.isnan(cerr[unknown]).all() and not np.isnan(np.delete(cerr, unknown)).any()
    assert (result.outcome.cerr_final_deg is None) == (len(steps) - 1 in unknown)
    # Step 1 is where the robots' memory is the truth (they start with exact information), so there
    # the true Cerr must agree: 64 deg, far from converged.
    assert 1 not in claimed
    first = steps[0]
    if None not in first["offset"]:
        truth = float(true_cerr(np.array(first["positions"]), np.array(first["target"])))
        assert float(memory_cerr(first["offset"])) == pytest.approx(truth, abs=1e-6)


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(240)
def test_a_racy_realtime_constant_run_converges_only_where_the_true_cerr_does(tmp_path: Path) -> None:
    result, steps = racy_realtime_run(tmp_path, "constant")
    assert 1 not in assert_claims_only_known_convergence(result, steps)
