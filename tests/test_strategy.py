"""The strategy interface: the example of docs/strategies.md runs in the engine and equals itself in
a lockstep team; bad strategies are refused in one line."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import msgspec
import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.laws import Trigger
from ringtrack.agents.strategy import strategy_class
from ringtrack.agents.summary import summarise
from ringtrack.bus.messages import robot_message_bytes
from ringtrack.tools.team.plan import TeamPlan
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.scenario import load_scenario
from tests.helpers import RINGTRACK, assert_equals_engine, lockstep_run, scenario

pytestmark = [pytest.mark.processes, pytest.mark.timeout(240)]

DOC = Path(__file__).resolve().parent.parent / "docs" / "strategies.md"


def example(tmp_path: Path) -> Path:
    """The documented example strategy, extracted from docs/strategies.md into a file of its own."""
    match = re.search(r"<!-- example: (\S+) -->\n```python\n(.*?)```", DOC.read_text(), re.S)
    assert match, "docs/strategies.md has no example block"
    path = tmp_path / match.group(1)
    path.write_text(match.group(2))
    return path


def test_documented_example_runs_in_simulate(tmp_path: Path) -> None:
    path = example(tmp_path)
    summary = tmp_path / "summary.json"
    completed = subprocess.run([*RINGTRACK, "simulate", "paper-stationary", "--strategy", str(path), "--steps", "400",
                                "--json", str(summary)], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    result = json.loads(summary.read_text())
    assert result["strategy"] == "heartbeat" and result["steps"] == 400
    # The heartbeat: no memory reaches 41 steps, and it polls at least where the self-triggered rule does.
    history = engine.run(scenario(strategy=str(path), max_steps=400))
    paper = engine.run(scenario(strategy="self", max_steps=400))
    assert history.ages.max() <= 40
    assert paper.ages.max() > 40  # the rule alone stays silent longer
    beats = (history.triggers & int(Trigger.SCHEDULE)) != 0
    assert beats.any() and np.all(history.ages.max(axis=-1)[beats] == 40)
    assert result["triggers"]["total"] == int((history.triggers != 0).sum())


def test_documented_example_lockstep_team_equals_the_engine(tmp_path: Path) -> None:
    path = example(tmp_path)
    _, log = lockstep_run(scenario(strategy=str(path), max_steps=200), tmp_path / "runs")
    logged = assert_equals_engine(log)
    assert ((logged.triggers & int(Trigger.SCHEDULE)) != 0).any()


@pytest.mark.parametrize(("content", "problem"), [
    (None, "'lazy' is not a registered strategy nor a Python file; give one of belief, constant, plan, relay, self or the path "
           "of a .py file that defines a Strategy"),
    ("import numpy\n", "defines 0 subclasses of ringtrack.agents.strategy.Strategy; define exactly one"),
    ("raise RuntimeError('boom')\n", "the strategy file failed to load (RuntimeError: boom); fix the file"),
    ("from ringtrack.agents.strategy import Strategy\nclass Mine(Strategy):\n    name = 'self'\n",
     "Mine.name is 'self'; give it a name of its own (not one of belief, constant, plan, relay, self)"),
], ids=["unknown", "empty", "broken", "taken-name"])
def test_bad_strategies_are_refused_in_one_line(tmp_path: Path, content: str | None, problem: str) -> None:
    value = "lazy"
    if content is not None:
        value = str(tmp_path / "mine.py")
        Path(value).write_text(content)
    completed = subprocess.run([*RINGTRACK, "simulate", "--strategy", value], capture_output=True, text=True,
                               timeout=60)
    assert completed.returncode == 2
    prefix = f"ringtrack: error: --strategy {value}: " + ("" if content is None else f"{value}: ")
    assert completed.stderr == prefix + problem + "\n"


def test_a_scenario_file_names_its_strategy(tmp_path: Path) -> None:
    text = (Path(__file__).resolve().parent.parent / "scenarios" / "paper-stationary.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('[strategy]\nname = "self"', '[strategy]\nname = "lazy"'))
    completed = subprocess.run([*RINGTRACK, "simulate", str(bad)], capture_output=True, text=True, timeout=60)
    assert completed.returncode == 2
    assert completed.stderr.startswith(f"ringtrack: error: {bad}: strategy.name: 'lazy' is not a registered")
    needs = subprocess.run([*RINGTRACK, "simulate", "authors-moving", "--strategy", "belief", "--estimation",
                            "centralized"], capture_output=True, text=True, timeout=60)
    assert needs.returncode == 2
    assert needs.stderr == ("ringtrack: error: --strategy belief: the belief strategy needs estimation.mode = "
                            "'decentralized' (it is 'centralized'); give --estimation decentralized\n")


def test_summary_figures_of_a_moving_target_are_settled_means() -> None:
    moving = engine.run(load_scenario("authors-moving", max_steps=400))
    result = summarise(moving, settle=300)
    assert result.from_step == 300
    assert result.cerr_mean_deg == pytest.approx(float(moving.cerr_true[300:, 0].mean()), rel=1e-12)
    assert result.terr_mean == pytest.approx(float(moving.terr[300:, 0].mean()), rel=1e-12)
    assert result.robot_messages == int(moving.sent.sum()) == 4 * int((moving.triggers != 0).sum())
    still = summarise(engine.run(scenario(max_steps=100)))
    assert still.cerr_mean_deg is None and "cerr_mean_deg" not in msgspec.json.encode(still).decode()
    assert still.robot_messages == int(engine.run(scenario(max_steps=100)).sent.sum())


CARRYING = '''
import numpy as np
from ringtrack.agents.strategy import SelfTriggered


class Carrying(SelfTriggered):
    name = "carrying"
    reply_fields = 2

    def reply_content(self, controller):
        return np.stack([controller.theta, controller.theta], axis=-1)
'''


@pytest.mark.processes
def test_the_engine_counts_the_bytes_of_replies_that_carry_a_strategys_content(tmp_path: Path) -> None:
    """A reply with ``reply_fields`` floats is a CarryingReply: the engine counts its exact size, and
    a lockstep team publishes the same bytes per robot and step (assert_equals_engine compares them)."""
    path = tmp_path / "carrying.py"
    path.write_text(CARRYING)
    plain = engine.run(load_scenario("paper-stationary", strategy="self", max_steps=60), record_positions=False)
    carrying = engine.run(load_scenario("paper-stationary", strategy=str(path), max_steps=60),
                          record_positions=False)
    assert np.array_equal(plain.triggers, carrying.triggers)  # the same rule: only the replies grow
    assert plain.requests is not None and plain.sent_bytes is not None and carrying.sent_bytes is not None
    extra = int(robot_message_bytes("reply", 1, 0, 1, content=[0.5, 0.5]) - robot_message_bytes("reply", 1, 0, 1))
    assert extra == 1 + 2 * 9  # the array header of two floats, and each float 9 bytes (angles are not whole)
    assert int(carrying.sent_bytes.sum() - plain.sent_bytes.sum()) == extra * int(plain.requests.sum())
    _, log = lockstep_run(load_scenario("paper-stationary", strategy=str(path), max_steps=60), tmp_path)
    assert_equals_engine(log)


@pytest.mark.processes
@pytest.mark.realtime
@pytest.mark.timeout(300)
@pytest.mark.parametrize("name", ["plan", "belief"])
def test_every_strategy_runs_in_realtime_with_faults_and_counts_every_message(tmp_path: Path, name: str) -> None:
    """plan (known target) and belief (moving target, decentralized) over Zenoh on the realtime
    clock with lost and duplicated links: the run ends, every message is accounted for (the fault
    identity, the monitor equal to the senders) and plan's own traffic is there (replies longer
    than plain ones). What the team achieves depends on the load; what is
    counted does not."""
    name_of = {"plan": "paper-stationary", "belief": "authors-moving"}[name]
    team = load_scenario(name_of, strategy=name, max_steps=150, drop=0.2, duplicate=0.1)
    result = spawn_team(TeamPlan(scenario=team, clock="realtime", rate=10.0, runs=tmp_path, dashboard=False))
    assert result.exit_code == 0 and result.end_reason in ("done", "converged")
    assert result.monitor_equals_senders is True
    faults = result.faults
    assert faults["dropped"] > 0 and faults["duplicated"] > 0
    assert faults["sent"] + faults["duplicated"] == faults["delivered"] + faults["dropped"]
    if name == "plan":  # a realtime team's first steps always poll; whether a belief is pushed depends on
        # the load (tests/test_belief.py holds lockstep pushes to the engine's, message for message)
        traffic = result.by_kind["reply"]
        assert traffic["messages"] > 0
        assert traffic["bytes"] > traffic["messages"] * int(robot_message_bytes("reply", 1, 0, 1))


def test_a_strategy_file_is_loaded_as_it_is_now(tmp_path: Path) -> None:
    """A process that lives on (a cluster's worker) runs a strategy file edited since it first
    loaded it as the file is now, and loads an unchanged file once."""
    path = example(tmp_path)
    first = strategy_class(str(path))
    assert strategy_class(str(path)) is first and first.name == "heartbeat"
    path.write_text(path.read_text().replace('name = "heartbeat"', 'name = "heartbeat_edited"'))
    assert strategy_class(str(path)).name == "heartbeat_edited"
