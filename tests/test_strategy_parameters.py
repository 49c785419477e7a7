"""Strategies own their knowledge: each declares its parameters, a scenario's ``[strategy]`` section
sets them (checked in one line naming ``strategy.KEY`` and the fix, before any work), ``ringtrack
strategies`` lists them, and which Cerr a run reports comes from the strategy, not from its name."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.strategy import (
    REGISTRY,
    Strategy,
    StrategyError,
    StrategyParameter,
    check_strategy,
    describe_strategies,
    strategy_class,
    strategy_for,
)
from ringtrack.tools.cli import build_parser, main
from ringtrack.tools.cli.options import scenario_from_arguments
from ringtrack.world.metrics import converged, strategy_cerr, true_cerr
from ringtrack.world.scenario import Scenario, ScenarioError, apply_overrides, load_scenario, parse_scenario, resolve
from ringtrack.world.scenario_files import shipped_scenarios
from ringtrack.world.state import WorldState
from tests.test_strategy import example

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"


def with_strategy(tmp_path: Path, section: str, base: str = "paper-stationary") -> Path:
    """A copy of a shipped scenario whose ``[strategy]`` section is ``section``."""
    text = (SCENARIOS / f"{base}.toml").read_text()
    assert '[strategy]\nname = "self"\n' in text
    path = tmp_path / "scenario.toml"
    path.write_text(text.replace('[strategy]\nname = "self"\n', section))
    return path


def refused(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """What ``ringtrack ARGV`` says on stderr when it refuses its input (exit 2, no output)."""
    assert main(list(argv)) == 2
    captured = capsys.readouterr()
    assert captured.out == ""  # refused before any work
    return captured.err


# ---------------------------------------------------------------------------- a strategy from a file
def test_a_file_strategy_takes_its_parameter_from_the_strategy_section(tmp_path: Path) -> None:
    heartbeat = example(tmp_path)  # docs/strategies.md's example: declares max_age (steps, default 40)
    scenario = load_scenario(str(with_strategy(tmp_path, f'[strategy]\nname = "{heartbeat}"\nmax_age = 25\n')),
                             max_steps=400)
    strategy = check_strategy(scenario)
    assert strategy.name == "heartbeat" and strategy.values == {"max_age": 25}
    assert strategy.max_age == 25  # type: ignore[attr-defined]
    assert check_strategy(load_scenario("paper-stationary", strategy=str(heartbeat))).max_age == 40  # type: ignore[attr-defined]
    tight, default = engine.run(scenario), engine.run(load_scenario("paper-stationary", strategy=str(heartbeat),
                                                                   max_steps=400))
    assert tight.ages.max() <= 25 < default.ages.max() <= 40  # the parameter is what the rule uses
    # The table of a strategy that runs in the named one's place: [strategy.heartbeat] for --strategy FILE.
    tabled = with_strategy(tmp_path, '[strategy]\nname = "self"\n\n[strategy.heartbeat]\nmax_age = 30\n')
    assert check_strategy(load_scenario(str(tabled))).values == {}  # the self strategy has no parameters
    assert check_strategy(load_scenario(str(tabled), strategy=str(heartbeat))).max_age == 30  # type: ignore[attr-defined]


HEARTBEAT_PROBLEMS = [
    ("max_age = 0", "strategy.max_age must be >= 1 (it is 0); give an integer >= 1 (default 40)"),
    ("max_age = 2.5", "strategy.max_age must be an integer (it is 2.5); give an integer >= 1 (default 40)"),
    ('max_age = "old"', 'strategy.max_age must be an integer (it is "old"); give an integer >= 1 (default 40)'),
    ("max_age = true", "strategy.max_age must be an integer (it is true); give an integer >= 1 (default 40)"),
    ("maxage = 3", "strategy.maxage: the heartbeat strategy has no parameter 'maxage'; give one of max_age"),
]


@pytest.mark.parametrize(("line", "problem"), HEARTBEAT_PROBLEMS, ids=["bound", "float", "string", "bool", "key"])
def test_bad_values_of_a_file_strategys_parameter_are_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], line: str, problem: str) -> None:
    heartbeat = example(tmp_path)
    scenario = with_strategy(tmp_path, f'[strategy]\nname = "{heartbeat}"\n{line}\n')
    assert refused(capsys, "simulate", str(scenario)) == f"ringtrack: error: {scenario}: {problem}\n"


@pytest.mark.parametrize(("section", "problem"), [
    ('name = "belief"\npush_gate = 0', "strategy.push_gate must be > 0 (it is 0); give a number > 0 (default 2.0)"),
    ('name = "belief"\npush_gate = "wide"',
     'strategy.push_gate must be a number (it is "wide"); give a number > 0 (default 2.0)'),
    ('name = "self"\npush_gate = 2.0',
     "strategy.push_gate: the self strategy has no parameter 'push_gate'; it has no parameters; remove the key"),
    ('name = "plan"\nplan_horizon = 20000',
     "strategy.plan_horizon must be <= 10000 (it is 20000); give an integer >= 0 and <= 10000 (default 10)"),
    ('name = "plan"\n\n[strategy.plan]\nplan_horizon = -1',
     "strategy.plan.plan_horizon must be >= 0 (it is -1); give an integer >= 0 and <= 10000 (default 10)"),
], ids=["belief-bound", "belief-type", "self-unknown", "plan-bound", "plan-table"])
def test_bad_values_of_a_registered_strategys_parameters_are_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], section: str, problem: str) -> None:
    scenario = with_strategy(tmp_path, f"[strategy]\n{section}\n")
    assert refused(capsys, "simulate", str(scenario)) == f"ringtrack: error: {scenario}: {problem}\n"
    # A robot or world process refuses it as it starts (it builds the strategy from the same section).
    with pytest.raises(StrategyError) as error:
        check_strategy(load_scenario(str(scenario)))
    assert str(error.value) == problem


def test_the_strategy_section_holds_only_plain_values(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = with_strategy(tmp_path, '[strategy]\nname = "self"\ngate = [1, 2]\n')
    assert refused(capsys, "simulate", str(scenario)) == (
        f"ringtrack: error: {scenario}: strategy.gate: expected a boolean, a number or a string, got `array`; "
        "fix the value\n")
    nameless = with_strategy(tmp_path, "[strategy]\nname = 3\n")
    assert refused(capsys, "simulate", str(nameless)) == (
        f"ringtrack: error: {nameless}: strategy.name: expected a registered strategy's name or the path of a .py "
        'file, e.g. "self"; fix the value\n')


def test_declarations_are_checked_when_a_strategy_class_is_written() -> None:
    with pytest.raises(StrategyError, match="declare bool, int, float or str"):
        StrategyParameter("gates", list, [])  # type: ignore[arg-type]
    with pytest.raises(StrategyError, match=r"its default must be > 0 \(it is 0\); declare a default that is a number"):
        StrategyParameter("gate", float, 0, gt=0)
    with pytest.raises(StrategyError, match="declare an identifier other than 'name'"):
        StrategyParameter("name", str, "x")
    with pytest.raises(StrategyError, match="over a member of Strategy"):
        type("Clash", (Strategy,), {"name": "clash", "parameters": (StrategyParameter("triggers", int, 1),)})


# ---------------------------------------------------------------------------- the scenario file
def test_the_old_control_strategy_key_still_names_the_strategy() -> None:
    text = (SCENARIOS / "paper-stationary.toml").read_text().replace('[strategy]\nname = "self"\n', "")
    old = text.replace("[control]\n", '[control]\nstrategy = "plan"\n')
    assert resolve(parse_scenario(old, "old.toml"), "old.toml").strategy.name == "plan"
    both = old.replace("[control]\n", '[strategy]\nname = "self"\n\n[control]\n')
    with pytest.raises(ScenarioError) as error:
        parse_scenario(both, "both.toml")
    assert str(error.value) == ("both.toml: control.strategy and strategy.name both name the strategy; "
                                "keep strategy.name only")
    moved = text.replace("[control]\n", "[control]\nplan_horizon = 5\n")
    with pytest.raises(ScenarioError, match=r"unknown key 'plan_horizon' in \[control\]; allowed keys: law, .*; "
                                            r"a strategy's own parameters go in \[strategy\]$"):
        parse_scenario(moved, "moved.toml")


def test_the_strategy_section_round_trips_through_a_run_logs_toml(tmp_path: Path) -> None:
    path = with_strategy(tmp_path, '[strategy]\nname = "plan"\nplan_horizon = 4\n\n[strategy.belief]\npush_gate = 1.5\n')
    scenario = load_scenario(str(path))
    assert scenario.strategy.name == "plan" and scenario.strategy.values == (("plan_horizon", 4),)
    assert scenario.strategy.table("belief") == {"push_gate": 1.5}
    again = resolve(parse_scenario(scenario.to_toml(), "run"), "run")  # what read_log does with a run's header
    assert again.strategy == scenario.strategy
    assert check_strategy(again).plan_horizon == 4  # type: ignore[attr-defined]


def test_no_shipped_scenario_sets_a_strategy_parameter() -> None:
    """Every shipped scenario runs each registered strategy with its defaults (nothing tuned by hand
    per scenario)."""
    for name in shipped_scenarios():
        choice = load_scenario(name).strategy
        assert not choice.values and not choice.tables, name


def test_overrides_set_the_parameters_of_the_strategy_that_runs() -> None:
    gazebo = load_scenario("gazebo-moving", strategy="belief")
    assert check_strategy(gazebo).push_gate == 2.0  # type: ignore[attr-defined]  # the default
    swept = load_scenario("gazebo-moving", strategy="belief", strategy_parameters={"belief": {"push_gate": 3.0}})
    assert check_strategy(swept).push_gate == 3.0  # type: ignore[attr-defined]  # a gate sweep wins over the file
    planned = load_scenario("paper-stationary", strategy="plan", strategy_parameters={"plan_horizon": 4})
    assert check_strategy(planned).plan_horizon == 4  # type: ignore[attr-defined]
    # --strategy OTHER: the plain keys were the named strategy's and stay behind; tables for others are ignored.
    assert check_strategy(resolve(apply_overrides(planned.spec, strategy="self"))).values == {}
    self_with_plan_table = load_scenario("paper-stationary", strategy_parameters={"plan": {"plan_horizon": 3}})
    assert check_strategy(self_with_plan_table).name == "self"


# ---------------------------------------------------------------------------- ringtrack strategies
def test_ringtrack_strategies_lists_every_strategy_and_its_parameters(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["strategies"]) == 0
    listed = capsys.readouterr().out
    for name in REGISTRY:
        cls = strategy_class(name)
        assert f"{name} ({cls.label})" in listed if cls.label else f"{name}:" in listed
        for parameter in cls.parameters:
            assert parameter.name in listed and parameter.units in listed and str(parameter.default) in listed
    assert "push_gate" in listed and "plan_horizon" in listed and "self-triggered" in listed
    heartbeat = example(tmp_path)
    assert main(["strategies", str(heartbeat), "--json"]) == 0
    described = json.loads(capsys.readouterr().out)
    assert [entry["name"] for entry in described] == [*REGISTRY, "heartbeat"]
    assert described[-1]["parameters"] == [{"name": "max_age", "type": "int", "default": 40, "units": "steps",
                                            "help": "poll once a neighbour's memory is this old",
                                            "expects": "an integer >= 1"}]
    assert {entry["name"]: entry["cerr"] for entry in described}["constant"] == "true"
    assert [d.name for d in describe_strategies()] == list(REGISTRY)


# ---------------------------------------------------------------------------- Cerr from the strategy
def test_which_cerr_a_run_reports_is_the_strategys_to_say() -> None:
    assert strategy_for("constant").cerr == "true" and strategy_for("self").cerr == "memory"
    with pytest.raises(ValueError, match="Cerr source 'constant'; use one of memory, true"):
        strategy_cerr("constant", 1.0, 2.0)  # type: ignore[arg-type]  # a strategy's name is no source
    scenario = load_scenario("paper-stationary", strategy="constant")
    history = engine.run(scenario, until_converged=True)
    assert np.array_equal(history.cerr, history.cerr_true) and history.ctime[0] == 745  # tests/test_engine.py
    assert history.positions is not None
    # The world of a converged constant run, where no robot has reported an offset yet: the true Cerr
    # (the constant strategy's) says converged, the memory-based one (unknown offsets) never does.
    truly, by_memory = (WorldState(scenario, scenario.seed, 1, 10, cerr=cerr) for cerr in ("true", "memory"))
    for world in (truly, by_memory):
        world.positions = history.positions[-1, 0]
    assert converged(true_cerr(truly.positions, truly.target), np.rad2deg(scenario.threshold))
    assert truly.converged() and not by_memory.converged()


def test_every_declared_parameter_has_a_flag_that_sets_it_where_its_strategy_runs() -> None:
    """The flags come from the declarations (``plan_horizon``: ``--plan-horizon``): each sets its
    strategy's parameter, checked by the declaration before any work; another strategy ignores it."""
    declared = {parameter.name: name for name in REGISTRY for parameter in strategy_class(name).parameters}
    assert declared == {"plan_horizon": "plan", "push_gate": "belief", "terr_ratio": "relay"}

    def parsed(*flags: str) -> Scenario:
        return scenario_from_arguments(build_parser(["simulate"]).parse_args(["simulate", *flags]))

    assert check_strategy(parsed("authors-moving", "--strategy", "belief", "--push-gate", "3.5")).push_gate == 3.5
    assert check_strategy(parsed("--strategy", "plan", "--plan-horizon", "4")).plan_horizon == 4
    assert check_strategy(parsed("authors-moving", "--strategy", "relay", "--terr-ratio", "1.5")).terr_ratio == 1.5
    assert parsed("--strategy", "self", "--plan-horizon", "4").strategy.table("plan") == {"plan_horizon": 4}
    parser = build_parser(["simulate"])
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "--push-gate", "0"])


def test_a_bad_parameter_flag_is_one_line_naming_it(capsys: pytest.CaptureFixture[str]) -> None:
    assert pytest.raises(SystemExit, main, ["simulate", "--plan-horizon", "-1"]).value.code == 2
    assert capsys.readouterr().err == ("ringtrack: error: argument --plan-horizon: '-1': must be >= 0 (it is -1); "
                                       "give an integer >= 0 and <= 10000 (see 'ringtrack simulate --help')\n")
