"""The plan strategy (agents/plan.py, docs/algorithms.md section 17): replies carry the replier's
committed plan, so the requester's prediction sets are tighter than the paper's and still contain
the true neighbour every step."""

from __future__ import annotations

import re
from pathlib import Path

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.agents import engine
from ringtrack.agents.engine import fault_totals
from ringtrack.agents.node import RobotNode
from ringtrack.agents.plan import PlanController, PlanStrategy, no_plan, prediction_set
from ringtrack.agents.strategy import StrategyError, check_strategy
from ringtrack.bus.counting import totals_by_category
from ringtrack.bus.keys import Route
from ringtrack.bus.messages import (
    NONCE_BASE,
    SCHEMA,
    CarryingReply,
    Measurement,
    Reply,
    Request,
    compact,
    decode,
    encode,
    robot_message_bytes,
)
from ringtrack.tools.cli import build_parser
from ringtrack.tools.cli.options import scenario_from_arguments
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.geometry import angle_of
from ringtrack.world.metrics import ring_order_kept
from ringtrack.world.scenario import Scenario, ScenarioError, load_scenario, resolve
from tests.helpers import assert_equals_engine, engine_twin, lockstep_run
from tests.test_dashboard import final_frame

# Containment is checked to this many radians: the world puts robots on the boundary
# (boundary_point), so a true angle differs from the planned one by rounding (about 1e-15 rad).
CONTAINMENT_TOLERANCE = 1e-9


def random_start(strategy: str = "plan", **overrides: object) -> Scenario:
    """paper-stationary with a seeded random start (as the stationary experiment runs it)."""
    spec = load_scenario("paper-stationary", strategy=strategy, **overrides).spec
    return resolve(msgspec.structs.replace(spec, team=msgspec.structs.replace(spec.team, angles_deg=None)))


def set_excess(controller: PlanController, positions: np.ndarray, target: np.ndarray) -> float:
    """How far (radians) a true neighbour angle lies outside the set its neighbour holds for it, at
    worst over every robot and side whose neighbour is known (<= 0: every one inside)."""
    true = angle_of(positions, target)
    low_minus, high_minus, low_plus, high_plus = controller.sets()
    worst = -np.inf
    for neighbour, low, high, known in ((np.roll(true, 1, axis=-1), low_minus, high_minus, controller.before.known),
                                        (np.roll(true, -1, axis=-1), low_plus, high_plus, controller.after.known)):
        above = np.mod(neighbour - low + np.pi, 2 * np.pi) - np.pi  # neighbour - low, wrapped
        excess = np.maximum(-above, above - (high - low))
        worst = max(worst, float(np.where(known, excess, -np.inf).max()))
    return worst


def checked_run(scenario: Scenario, seeds: list[int], steps: int) -> engine.History:
    """An engine run that asserts, every step, ring order and that every known neighbour is inside
    the set its neighbour holds for it."""
    def watch(step: int, controller: PlanController, positions: np.ndarray) -> None:
        assert ring_order_kept(scenario.region, positions).all(), f"order broken at step {step}"
        if step > 1:
            excess = set_excess(controller, positions, scenario.target)
            assert excess <= CONTAINMENT_TOLERANCE, f"a neighbour {excess:.3g} rad outside its set at step {step}"

    return engine.run(scenario, seeds, steps=steps, record_positions=False, watch=watch)


# ---------------------------------------------------------------------------- the prediction set
def test_prediction_set_is_the_papers_without_a_plan_and_the_envelope_with_one() -> None:
    params = load_scenario("paper-stationary").control
    w = params.max_step
    centre, half = prediction_set(13, 10, no_plan(10), params)
    assert centre == 0.0 and half == pytest.approx(3 * w, abs=1e-15)
    plan = no_plan(10)._replace(until=np.array(20), low=np.array(-0.5 * w), high=np.array(4 * w),
                                shift=np.array(2 * w))
    centre, half = prediction_set(13, 10, plan, params)  # [max(-0.5w, -3w), min(4w, 3w)]
    assert (centre - half, centre + half) == pytest.approx((-0.5 * w, 3 * w), abs=1e-15)
    centre, half = prediction_set(23, 10, plan, params)  # D +- w (23 - 20)
    assert (centre - half, centre + half) == pytest.approx((-w, 5 * w), abs=1e-15)


# ---------------------------------------------------------------------------- safety, every step
@settings(max_examples=15)
@given(robots=st.integers(3, 12), seed=st.integers(0, 10_000), horizon=st.sampled_from([0, 3, 50]),
       drop=st.sampled_from([0.0, 0.3]), law=st.sampled_from(["prop", "deadbeat"]))
def test_sets_contain_the_true_neighbours_and_order_is_kept(robots: int, seed: int, horizon: int, drop: float,
                                                            law: str) -> None:
    scenario = random_start(robots=robots, seed=seed, strategy_parameters={"plan_horizon": horizon}, drop=drop,
                            law=law)
    checked_run(scenario, [seed, seed + 1], steps=250)


def test_paper_example_keeps_its_sets_every_step_to_convergence() -> None:
    scenario = load_scenario("paper-stationary", strategy="plan")
    history = checked_run(scenario, [0], steps=800)
    assert 0 < history.ctime[0] <= 800


def test_horizon_zero_is_the_papers_rule() -> None:
    """H = 0: every plan ends where it starts (r = D = 0, T' = k), the paper's self-triggered rule."""
    seeds = list(range(8))
    planned = engine.run(random_start(strategy_parameters={"plan_horizon": 0}), seeds, steps=500,
                         record_positions=False)
    paper = engine.run(random_start("self"), seeds, steps=500, record_positions=False)
    assert np.array_equal(planned.triggers, paper.triggers)
    assert np.max(np.abs(planned.angles - paper.angles)) < 1e-9


@pytest.mark.slow
@pytest.mark.parametrize(("robots", "com_bar_limit"), [(6, 0.14), (20, 0.21), (30, 0.21)])
def test_plan_converges_with_less_talk_than_self(robots: int, com_bar_limit: float) -> None:
    """paper-stationary, seeds 0-29: plan converges in every trial, mean Ctime no worse than self's,
    and Com-bar within the limit (self: 0.199, 0.314, 0.335)."""
    seeds = list(range(30))
    runs = {strategy: engine.run(random_start(strategy, robots=robots), seeds, until_converged=True,
                                 record_positions=False) for strategy in ("self", "plan")}
    assert (runs["plan"].ctime > 0).all() and (runs["self"].ctime > 0).all()
    assert runs["plan"].ctime.mean() <= runs["self"].ctime.mean()
    assert runs["plan"].com_bar.mean() <= com_bar_limit < runs["self"].com_bar.mean()


# ---------------------------------------------------------------------------- messages and bytes
@pytest.mark.parametrize(("step", "ahead"), [(1, 1), (200, 10), (70_000, 100)])
def test_plan_reply_bytes_are_counted_exactly(step: int, ahead: int) -> None:
    """A plan travels as the strategy's four carried floats; a robot with no plan beyond the step
    (all zeros) sends a plain reply, of a plain reply's size."""
    fields = PlanStrategy().reply_fields
    carried = (float(ahead), 0.0, 0.02, 0.015)  # a course that only turns counter-clockwise: r- = 0
    reply = CarryingReply(SCHEMA, NONCE_BASE + 9, step, 2, 1, NONCE_BASE + 3, (1.5, 2.5), carried=compact(carried))
    assert len(encode(reply)) == robot_message_bytes("reply", step, 2, 1, content=carried)
    assert decode(encode(reply), Route("r1", "r2", "reply"), NONCE_BASE + 9, 6) == reply
    plain = Reply(SCHEMA, NONCE_BASE + 9, step, 2, 1, NONCE_BASE + 3, (1.5, 2.5))
    assert len(encode(plain)) == robot_message_bytes("reply", step, 2, 1)  # other strategies: unchanged
    assert len(encode(plain)) == robot_message_bytes("reply", step, 2, 1, content=(0.0,) * fields)  # no plan


def test_engine_counts_the_bigger_replies() -> None:
    """Bytes the robots publish: requests and replies by their exact sizes. A plan reply is 5 to 29
    bytes longer than a plain one (an array header, the horizon as a one-byte integer and three
    radians, each a 9-byte float or, when zero, one byte); a robot that polls at the step it is
    asked has no plan beyond it and sends a plain reply."""
    steps = 75
    history = engine.run(random_start(seed=3), [3], steps=steps, record_positions=False)
    assert history.sent_bytes is not None and history.requests is not None
    robots = history.triggers.shape[2]
    plain, planned = 0, 0
    for row in range(steps):
        for robot in range(robots):
            for side, neighbour in ((0, (robot - 1) % robots), (1, (robot + 1) % robots)):
                copies = int(history.requests[row, 0, robot, side])
                plain += copies * int(robot_message_bytes("request", row + 1, robot, neighbour)
                                      + robot_message_bytes("reply", row + 1, neighbour, robot))
                planned += copies * int(history.triggers[row, 0, neighbour] == 0)
    assert planned > 0  # replies that carried a plan
    extra = int(history.sent_bytes[:, 0].sum()) - plain
    assert 5 * planned <= extra <= 29 * planned
    assert extra > 5 * planned  # most plans have a non-zero envelope


# ---------------------------------------------------------------------------- scenario checks
@pytest.mark.parametrize(("overrides", "message"), [
    ({"estimation": "decentralized"}, "the plan strategy needs a known stationary target (estimation.mode = 'known'); "
                                      "use 'self' to estimate"),
    ({"communication_range": 9.0}, "the plan strategy needs unlimited communication; "
                                   "unset limits.communication_range or use 'self'"),
    ({"strategy_parameters": {"plan_horizon": -1}}, "strategy.plan_horizon must be >= 0 (it is -1); give an integer "
                                                    ">= 0 and <= 10000 (default 10)"),
    ({"strategy_parameters": {"plan_horizon": 2.5}}, "strategy.plan_horizon must be an integer (it is 2.5); give an "
                                                     "integer >= 0 and <= 10000 (default 10)"),
])
def test_unsupported_combinations_are_refused_in_one_line(overrides: dict, message: str) -> None:
    """The plan strategy's own checks (:meth:`PlanStrategy.check`) and its parameter's declaration,
    whether the scenario is checked in a process (check_strategy) or by a command."""
    with pytest.raises(StrategyError) as error:
        check_strategy(load_scenario("paper-stationary", strategy="plan", **overrides))
    assert str(error.value) == message
    if "strategy_parameters" in overrides:
        return  # --plan-horizon: argparse refuses these itself
    flags = {"estimation": ["--estimation", "decentralized"],
             "communication_range": ["--communication-range", "9"]}[next(iter(overrides))]
    with pytest.raises(ScenarioError) as refused:
        scenario_from_arguments(build_parser(["simulate"]).parse_args(["simulate", "--strategy", "plan", *flags]))
    assert str(refused.value) == f"--strategy plan: {message}"


def test_the_plan_horizon_flag_sets_the_strategys_parameter() -> None:
    def scenario_of(*flags: str) -> Scenario:
        return scenario_from_arguments(build_parser(["simulate"]).parse_args(["simulate", *flags]))

    assert check_strategy(scenario_of("--strategy", "plan", "--plan-horizon", "3")).plan_horizon == 3
    assert check_strategy(scenario_of("--strategy", "plan")).plan_horizon == 10
    with pytest.raises(SystemExit):  # the flag is checked by the parameter's declaration as it is parsed
        scenario_of("--strategy", "plan", "--plan-horizon", "20000")


# ---------------------------------------------------------------------------- the robot process
def test_a_buffered_request_is_answered_after_the_robot_decided() -> None:
    """A request that arrives before the robot's measurement is answered once it has decided its
    step: at step 1 it polls, so its plan ends at once (the paper's rule)."""
    scenario = load_scenario("paper-stationary", strategy="plan")
    node = RobotNode(1, scenario, NONCE_BASE, nonce=lambda: NONCE_BASE)
    assert node.handle(Request(SCHEMA, NONCE_BASE, 1, 0, 1, NONCE_BASE + 1)) == []
    position = tuple(scenario.start_positions(scenario.seed)[1])
    out = node.handle(Measurement(SCHEMA, NONCE_BASE, 1, 0.0, 1, position, 1.0))
    kinds = [type(message).__name__ for _, message in out]
    assert sorted(kinds) == ["Reply", "Request", "Request"]  # no plan beyond the step: a plain reply
    assert node.carried[1] == (0.0, 0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------- lockstep over Zenoh
@pytest.mark.processes
@pytest.mark.timeout(300)
@pytest.mark.parametrize("drop", [0.0, 0.2])
def test_lockstep_plan_team_equals_the_engine(tmp_path: Path, drop: float) -> None:
    """Angles to 1e-9 and every trigger equal to the engine's, and the bytes the robots published
    (plan replies included) equal to what the engine counts, per robot and step."""
    result, log = lockstep_run(load_scenario("paper-stationary", strategy="plan", max_steps=200, drop=drop), tmp_path)
    assert_equals_engine(log)
    # Every step, the team's true positions (as the world logged them) keep their order and lie in the
    # sets the robots' memory (the engine's, equal to the processes') holds for them.
    logged = [np.array(record["positions"]) for record in log.steps]

    def watch(step: int, controller: PlanController, positions: np.ndarray) -> None:
        assert ring_order_kept(log.scenario.region, logged[step - 1]).all(), step
        if step > 1:
            assert set_excess(controller, logged[step - 1][None], log.scenario.target) <= CONTAINMENT_TOLERANCE, step

    engine.run(log.scenario, [log.header["seed"]], steps=len(log.steps), record_positions=False, watch=watch)
    twin = engine_twin(log)
    assert twin.sent_bytes is not None
    logged_bytes = np.array([record["sent_bytes"] for record in log.steps])
    assert np.array_equal(logged_bytes, twin.sent_bytes[:, 0])
    assert result.messages["robot"] == int(twin.sent[:, 0].sum())


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_dashboard_monitor_and_run_log_count_plan_replies_with_faults(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """With dropped messages, the live dashboard's last frame, the monitor's totals, the run log's
    per-step bytes and the engine all count the same robot-to-robot messages and bytes."""
    monkeypatch.setenv("COLUMNS", "120")
    monkeypatch.setenv("LINES", "60")
    scenario = load_scenario("paper-stationary", strategy="plan", max_steps=80, drop=0.2)
    result = spawn_team(TeamPlan(scenario=scenario, runs=tmp_path, dashboard=True, quiet=True))
    assert result.exit_code == 0
    folder = Path(result.folder)
    log = read_log(folder / "log.jsonl")
    assert log.end is not None and log.end["consistent"] is True and log.end["late"] == 0
    robot = totals_by_category([tuple(row) for row in log.end["traffic"]])["robot"]
    twin = engine_twin(log)
    assert twin.sent_bytes is not None
    assert (robot["messages"], robot["bytes"]) == (int(twin.sent[:, 0].sum()), int(twin.sent_bytes[:, 0].sum()))
    assert sum(sum(record["sent_bytes"]) for record in log.steps) == robot["bytes"]
    assert fault_totals(twin)["dropped"] > 0
    frame = final_frame((folder / "monitor.stdout").read_text(), "paper-stationary · 6 robots")
    assert "plan strategy" in frame
    assert re.search(rf"robot-to-robot\s+{robot['messages']}\s+{robot['bytes']}\s", frame), frame
