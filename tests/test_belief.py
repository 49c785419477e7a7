"""The belief strategy: pushes past the gate, counted as robot-to-robot messages everywhere, and a
lockstep team over Zenoh that equals the engine, with and without faults."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.belief import mahalanobis_squared
from ringtrack.agents.summary import summarise
from ringtrack.bus.faults import FAULT_COUNTERS
from ringtrack.tools.runlog.log import history_from_log, read_log
from ringtrack.tools.studies.gates import with_gate
from ringtrack.world.scenario import load_scenario
from tests.helpers import RINGTRACK, engine_twin, lockstep_run
from tests.test_accounting import assert_one_count, robot_links

STEPS = 200


def belief(**overrides: object):
    return load_scenario("authors-moving", strategy="belief", max_steps=STEPS, **overrides)


def test_gate_is_the_mahalanobis_distance() -> None:
    covariance = np.array([[4.0, 0.0], [0.0, 1.0]])
    assert mahalanobis_squared(np.array([2.0, 1.0]), np.zeros(2), covariance) == pytest.approx(1.0 + 1.0)
    batch = mahalanobis_squared(np.ones((3, 4, 2)), np.zeros((3, 4, 2)), np.broadcast_to(covariance, (3, 4, 2, 2)))
    assert batch.shape == (3, 4) and np.allclose(batch, 1.25)


def test_pushes_are_robot_to_robot_messages_and_follow_the_gate() -> None:
    history = engine.run(belief())
    assert history.pushes is not None and history.pushes.sum() > 0
    polled = history.triggers != 0
    pushing = history.pushes.sum(axis=-1) > 0
    assert not (pushing & polled).any()  # a robot that polls tells its belief in the requests
    requests = history.requests
    assert requests is not None
    assert np.array_equal(history.sent, engine.ring_traffic(requests) + history.pushes.sum(axis=-1))
    assert history.sent.sum() == history.received.sum() == engine.fault_totals(history)["published"]
    rows = {(kind, source, destination): count for kind, source, destination, count, _ in engine.link_traffic(history)}
    assert sum(count for (kind, *_), count in rows.items() if kind == "push") == int(history.pushes.sum())
    silent = engine.run(with_gate(belief(), 1e6))  # a gate nothing passes: only the paper's polls talk
    assert silent.pushes is not None and silent.pushes.sum() == 0
    assert silent.sent.sum() == 4 * int((silent.triggers != 0).sum())


def test_the_gate_set_in_the_strategy_section_is_the_gate_the_robots_use(tmp_path: Path) -> None:
    """``[strategy] push_gate``: the default gate written out changes nothing, a gate nothing passes
    silences the pushes (as ``with_gate``, the gate sweep's override), and a narrower one pushes more."""
    text = (Path(__file__).resolve().parent.parent / "scenarios" / "authors-moving.toml").read_text()

    def gated(gate: str) -> engine.History:
        path = tmp_path / f"gate-{gate}.toml"
        path.write_text(text.replace('[strategy]\nname = "self"\n', f'[strategy]\nname = "belief"\npush_gate = {gate}\n'))
        return engine.run(load_scenario(str(path), max_steps=STEPS))

    default, written = engine.run(belief()), gated("2.0")
    assert default.pushes is not None and written.pushes is not None and default.pushes.sum() > 0
    assert np.array_equal(default.pushes, written.pushes) and np.array_equal(default.triggers, written.triggers)
    silent, swept = gated("1e6"), engine.run(with_gate(belief(), 1e6))
    assert silent.pushes is not None and swept.pushes is not None and silent.pushes.sum() == swept.pushes.sum() == 0
    assert np.array_equal(silent.sent, swept.sent)
    narrow = gated("1")
    assert narrow.pushes is not None and narrow.pushes.sum() > default.pushes.sum()


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_lockstep_belief_team_equals_the_engine(tmp_path: Path) -> None:
    result, log = lockstep_run(belief(), tmp_path)
    logged, twin = history_from_log(log), engine_twin(log)
    assert logged.steps == twin.steps == STEPS
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-9
    assert logged.estimates is not None and twin.estimates is not None
    assert np.max(np.abs(logged.estimates - twin.estimates)) < 1e-9  # every robot's belief it steered by
    assert np.array_equal(logged.triggers, twin.triggers)
    assert np.array_equal(logged.sent, twin.sent) and np.array_equal(logged.received, twin.received)
    assert twin.pushes is not None and result.by_kind["push"]["messages"] == int(twin.pushes.sum()) > 0
    assert result.outcome.robot_messages == int(twin.sent.sum())
    spawned, simulated = summarise(logged, settle=100), summarise(twin, settle=100)  # as spawn's summary
    for key in ("robot_messages", "cerr_mean_deg", "terr_mean", "from_step"):
        assert getattr(spawned, key) == pytest.approx(getattr(simulated, key), rel=1e-9, abs=1e-12)


def run(command: str, folder: Path, flags: list[str]) -> tuple[dict, object]:
    summary, path = folder / f"{command}.json", folder / f"{command}.jsonl"
    extra = ["--runs", str(folder / "runs"), "--no-dashboard", "--clock", "lockstep"] if command == "spawn" else []
    completed = subprocess.run([*RINGTRACK, command, "authors-moving", "--strategy", "belief", *flags, "--steps",
                                str(STEPS), "--from-step", "100", *extra, "--json", str(summary), "--log", str(path)],
                               capture_output=True, text=True, timeout=280)
    assert completed.returncode == 0, completed.stderr
    return json.loads(summary.read_text()), read_log(path)


@pytest.mark.processes
@pytest.mark.timeout(300)
def test_belief_with_faults_counts_every_message_once(tmp_path: Path) -> None:
    flags = ["--drop", "0.2", "--duplicate", "0.1"]
    simulated, engine_log = run("simulate", tmp_path, flags)
    spawned, team_log = run("spawn", tmp_path, flags)
    count = assert_one_count(engine_log)
    assert assert_one_count(team_log) == count == simulated["robot_messages"] == spawned["outcome"]["robot_messages"]
    assert engine_log.end["faults"]["dropped"] > 0 and engine_log.end["faults"]["duplicated"] > 0
    assert team_log.end["consistent"] is True
    assert team_log.end["notes"].get("pushes_waited_out", 0) == 0  # every lost push is known lost at once (the
    # monitor sums the counters robots report and leaves out zeros)
    assert [record["sent_messages"] for record in team_log.steps] == \
        [record["sent_messages"] for record in engine_log.steps]
    assert robot_links(team_log.end["traffic"]) == robot_links(engine_log.end["traffic"])
    assert any(kind == "push" for kind, *_ in robot_links(team_log.end["traffic"]))
    assert {key: spawned["faults"][key] for key in FAULT_COUNTERS} == \
        {key: simulated["faults"][key] for key in FAULT_COUNTERS}
    assert spawned["outcome"]["terr_mean"] == pytest.approx(simulated["terr_mean"], rel=1e-9)
