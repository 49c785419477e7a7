"""``ringtrack experiment tracking`` (tools/studies/tracking.py): its rows against the engine's
history and the bound's formula, its ratios, batching, errors and figure."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.tools.cli import main
from ringtrack.tools.cli.experiment_tracking import verdict_line
from ringtrack.tools.studies.study import Execution
from ringtrack.tools.studies.tracking import (
    TrackingRow,
    TrackingVerdict,
    decentralized_strategies,
    tracking_experiment,
    tracking_verdict,
    with_ratios,
)
from ringtrack.world.bounds import random_walk_bound
from ringtrack.world.scenario import load_scenario
from ringtrack.world.scenario_generator import file_name, scenario_text

STEPS, SETTLE = 120, 20


@pytest.fixture(scope="module")
def walk(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A generated scenario with a random-walk target (scenario 1 of seed 0 cycles to random_walk)."""
    path = tmp_path_factory.mktemp("generated") / file_name(1)
    path.write_bytes(scenario_text(0, 1))
    assert "random_walk" in path.read_text()
    return path


def test_the_default_strategies_are_those_that_estimate_decentralized():
    assert decentralized_strategies() == ["constant", "self", "belief", "relay"]


def test_rows_against_the_engine_and_the_bound(walk: Path):
    """One trial: Terr, RMSE and the bound's RMSE recomputed from the engine's history and
    world.bounds; the centralized row is the reference (ratio 1), the others its multiples."""
    study = tracking_experiment([str(walk), "authors-moving"], trials=1, seed=3, strategies=["self"], steps=STEPS,
                                settle=SETTLE)
    assert [(row.scenario, row.strategy, row.estimation) for row in study.rows] == [
        ("gen-0001", "self", "decentralized"), ("gen-0001", "self", "centralized"),
        ("authors-moving", "self", "decentralized"), ("authors-moving", "self", "centralized")]
    walked, central = study.rows[0], study.rows[1]
    scenario = load_scenario(str(walk), strategy="self", estimation="decentralized", max_steps=STEPS)
    history = engine.run(scenario, [3])
    error = np.linalg.norm(history.estimates - history.targets[:, :, None, :], axis=-1)[SETTLE:, 0]
    assert walked.terr_mean == pytest.approx(error.mean(), rel=1e-9)
    assert walked.rmse == pytest.approx(math.sqrt((error**2).mean()), rel=1e-9)
    bound = random_walk_bound(history.positions[:, 0], history.targets[:, 0], 0.2,
                              (scenario.spec.target.speed_std * 0.1) ** 2, 1.0)
    # the study adds the bound (m^2, about 6e-4 here) in fixed point, each value to 2^-32 m^2
    assert walked.crb_rmse == pytest.approx(math.sqrt(bound[SETTLE:].mean()), rel=1e-6)
    assert walked.rmse_over_crb == pytest.approx(walked.rmse / walked.crb_rmse, rel=1e-12)
    assert walked.terr_over_crb == pytest.approx(walked.terr_mean / walked.crb_rmse, rel=1e-12)
    # the same starts and path; the robots moved about other estimates, so nearly the same geometry
    assert central.crb_rmse == pytest.approx(walked.crb_rmse, rel=1e-2) and central.crb_rmse != walked.crb_rmse
    assert central.terr_ratio == 1.0
    assert walked.terr_ratio == pytest.approx(walked.terr_mean / central.terr_mean, rel=1e-12)
    for row in study.rows:
        assert row.rmse >= row.terr_mean  # a root mean square is at least the mean
        assert (row.steps, row.settle, row.trials) == (STEPS, SETTLE, 1)
    assert [row.crb_rmse for row in study.rows[2:]] == [None, None]  # a circle: no bound
    assert [row.motion for row in study.rows] == ["random_walk"] * 2 + ["circle"] * 2


def test_batches_do_not_change_the_study(walk: Path):
    one, two = (tracking_experiment([str(walk)], trials=3, seed=0, strategies=["belief"], steps=60, settle=10,
                                    execution=Execution(batch=batch)) for batch in (1, 3))
    assert one.rows == two.rows


def test_the_settle_defaults_below_a_short_run(walk: Path):
    study = tracking_experiment([str(walk)], trials=1, seed=0, strategies=["constant"], steps=40)
    assert {row.settle for row in study.rows} == {39}


def test_a_folder_is_its_toml_files_and_the_figure_is_drawn(walk: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]):
    figure, output = tmp_path / "tracking.png", tmp_path / "tracking.json"
    assert main(["experiment", "tracking", str(walk.parent), "--strategies", "constant", "--trials", "1", "--steps",
                 "40", "--settle", "5", "--plot", str(figure), "--json", str(output), "--quiet", "--workers", "1"]) == 0
    assert figure.stat().st_size > 0
    written = json.loads(output.read_text())
    assert written["scenarios"] == [str(walk)]
    assert [row["estimation"] for row in written["rows"]] == ["decentralized", "centralized"]
    assert "gen-0001" in capsys.readouterr().out


@pytest.mark.parametrize(("arguments", "error"), [
    (["EMPTY"], "EMPTY: a folder without .toml files; give scenario files, a folder of them (ringtrack scenarios "
                "generate) or shipped names"),
    (["authors-moving", "--steps", "50", "--settle", "50"], "--settle 50: must be below the 50 steps of authors-moving"),
    (["authors-moving", "authors-moving"], "SCENARIO authors-moving: another scenario given is named "
                                           "'authors-moving' too; give each once"),
    (["authors-moving", "--strategies", "plan"], "--strategies: the plan strategy needs a known stationary target "
                                                 "(estimation.mode = 'known'); "),
])
def test_bad_input_gets_one_line(arguments: list[str], error: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    (tmp_path / "EMPTY").mkdir()
    arguments = [str(tmp_path / "EMPTY") if value == "EMPTY" else value for value in arguments]
    error = error.replace("EMPTY", str(tmp_path / "EMPTY"))
    assert main(["experiment", "tracking", *arguments, "--trials", "1", "--quiet", "--workers", "1"]) == 2
    assert capsys.readouterr().err.startswith(f"ringtrack: error: {error}")


def test_a_verdict_counts_the_scenarios_that_meet_the_goal_and_names_the_worst() -> None:
    """tracking_verdict: Terr at most 1.2x the centralized on at most its messages per robot-step,
    true Cerr within 1 degree; the worst of each with its scenario."""

    def row(scenario: str, estimation: str, terr: float, cerr: float, messages: float) -> TrackingRow:
        return TrackingRow(scenario=scenario, motion="circle", robots=6, strategy="relay" if estimation ==
                           "decentralized" else "self", estimation=estimation, trials=1, steps=10, settle=0,
                           terr_mean=terr, cerr_mean_deg=cerr, robot_messages_per_robot_step=messages, rmse=terr,
                           terr_ratio=None, crb_rmse=None, terr_over_crb=None, rmse_over_crb=None)

    rows = with_ratios([
        row("a", "decentralized", 0.12, 2.5, 0.5), row("a", "centralized", 0.10, 2.0, 1.0),  # meets it
        row("b", "decentralized", 0.13, 3.5, 0.9), row("b", "centralized", 0.10, 2.0, 1.0),  # Terr 1.3x, Cerr +1.5
        row("c", "decentralized", 0.10, 2.0, 1.2), row("c", "centralized", 0.10, 2.0, 1.0),  # messages 1.2x
    ])
    verdict = tracking_verdict(rows, "relay")
    assert (verdict.scenarios, verdict.met, verdict.cerr_met) == (3, 1, 2)
    assert (verdict.worst_terr_ratio, verdict.worst_terr_scenario) == (pytest.approx(1.3), "b")
    assert (verdict.worst_message_ratio, verdict.worst_message_scenario) == (pytest.approx(1.2), "c")
    assert (verdict.worst_cerr_excess_deg, verdict.worst_cerr_scenario) == (pytest.approx(1.5), "b")


def test_a_verdict_line_says_unknown_where_no_scenario_has_a_figure() -> None:
    """A scenario whose centralized Terr is 0 (a stationary target the robots know from the start)
    has no Terr ratio: the verdict says so rather than printing an empty one."""
    verdict = TrackingVerdict(strategy="self", scenarios=1, met=0, cerr_met=1, worst_terr_ratio=None,
                              worst_terr_scenario="", worst_message_ratio=8.3333, worst_message_scenario="square",
                              worst_cerr_excess_deg=0.0, worst_cerr_scenario="square")
    assert verdict_line(verdict, "self-triggered") == (
        "self-triggered: Terr <= 1.2x centralized on no more messages on 0 of 1 scenarios, true Cerr within 1 deg "
        "on 1; worst Terr unknown, messages 8.33x (square), Cerr +0.00 deg (square)")
