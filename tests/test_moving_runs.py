"""A moving target's run runs control.max_steps steps (simulate, spawn): convergence of the ring says
nothing of tracking, so it ends only a stationary target's run; --steps K still runs exactly K."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import msgspec
import pytest

from ringtrack.agents import engine
from ringtrack.tools.cli import main
from ringtrack.world.scenario import apply_overrides, load_scenario, resolve
from tests.helpers import RINGTRACK

STEPS = 60


@pytest.fixture
def loose(tmp_path: Path) -> Path:
    """authors-moving, 60 steps long, with a threshold every start meets at once (Ctime 1)."""
    scenario = load_scenario("authors-moving", max_steps=STEPS, threshold_deg=360.0)
    assert engine.run(scenario, until_converged=True, record_positions=False).ctime.tolist() == [1]
    path = tmp_path / "loose.toml"
    path.write_bytes(scenario.to_toml())
    return path


def test_simulate_runs_a_moving_target_to_max_steps(loose: Path, tmp_path: Path):
    summary = tmp_path / "summary.json"
    assert main(["simulate", str(loose), "--json", str(summary)]) == 0
    result = json.loads(summary.read_text())
    assert (result["steps"], result["ctime"]) == (STEPS, 1)
    assert main(["simulate", str(loose), "--steps", "7", "--json", str(summary)]) == 0
    assert json.loads(summary.read_text())["steps"] == 7


def test_simulate_still_ends_a_stationary_targets_run_at_convergence(tmp_path: Path):
    stationary = load_scenario("paper-stationary", max_steps=STEPS)
    path = tmp_path / "stationary.toml"
    path.write_bytes(resolve(apply_overrides(stationary.spec, threshold_deg=360.0)).to_toml())
    summary = tmp_path / "summary.json"
    assert main(["simulate", str(path), "--json", str(summary)]) == 0
    assert json.loads(summary.read_text())["steps"] == 1


@pytest.mark.parametrize("command", ["simulate", "spawn", "world"])
def test_help_says_a_moving_target_runs_max_steps(command: str, capsys: pytest.CaptureFixture[str]):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    assert "a moving target's runs control.max_steps steps" in " ".join(capsys.readouterr().out.split())


@pytest.mark.processes
def test_spawn_runs_a_moving_target_to_max_steps(loose: Path, tmp_path: Path):
    summary = tmp_path / "team.json"
    completed = subprocess.run([*RINGTRACK, "spawn", str(loose), "--runs", str(tmp_path / "runs"), "--no-dashboard",
                                "--json", str(summary)], capture_output=True, text=True, timeout=180)
    assert completed.returncode == 0, completed.stderr
    outcome = msgspec.json.decode(summary.read_bytes())["outcome"]
    assert (outcome["steps"], outcome["ctime"]) == (STEPS, 1)
