"""``ringtrack bench``: each benchmark runs for real (briefly) and reports what its JSON promises."""

from __future__ import annotations

import fcntl
import io
import json
import re
import time
from pathlib import Path

import pytest
from rich.console import Console

from ringtrack.bus.messages import SCHEMA, Reply, Request, encode
from ringtrack.tools.bench.bench import EngineProgress, engine_results, suite_ratios
from ringtrack.tools.bench.studies import two_process_ceiling
from ringtrack.tools.cli import main

pytestmark = pytest.mark.timeout(240)


@pytest.mark.processes
def test_latency_bench_times_real_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "latency.json"
    assert main(["bench", "latency", "--rounds", "300", "--warmup", "30", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["rounds"] == 300 and result["machine"]["cores"] >= 1
    assert 0 < result["median_us"] <= result["p99_us"]
    assert result["median_us"] < 1e6  # a hang or a timeout would show here, not a speed target
    assert all(value > 0 for value in result["cpu_us_per_round_trip"].values())
    assert "eclipse-zenoh" in result["machine"]["versions"]


@pytest.mark.processes
def test_emulator_bench_reports_speed_start_up_bytes_and_memory(tmp_path: Path) -> None:
    path = tmp_path / "emulator.json"
    arguments = ["bench", "emulator", "--robots", "3", "--steps", "40", "--robots-per-process", "3",
                 "--runs", str(tmp_path / "runs"), "--json", str(path)]
    assert main(arguments) == 0
    result = json.loads(path.read_text())
    (row,) = result["rows"]
    assert result["steps_per_s"] == row["steps_per_s"] > 0
    assert row["robots"] == 3 and row["robots_per_process"] == 3 and row["steps"] == 40
    assert row["startup_s"] > 0 and row["robot_process_rss_mib"] > 10
    # Wire bytes per message: a request's size does not depend on its values' magnitudes beyond
    # msgpack's integer widths, so it lies between the smallest and the largest possible encoding.
    smallest = len(encode(Request(SCHEMA, 0, 1, 0, 1, 0)))
    largest = len(encode(Request(SCHEMA, 2**32 - 1, 2**31, 2, 2, 2**32 - 1)))
    assert smallest <= row["bytes_per_message"]["request"] <= largest
    assert row["bytes_per_message"]["reply"] > row["bytes_per_message"]["request"]
    assert len(encode(Reply(SCHEMA, 0, 1, 0, 1, 0, (0.0, 0.0)))) <= row["bytes_per_message"]["reply"]


def test_engine_bench_reports_a_run_an_experiment_and_a_sweep(tmp_path: Path) -> None:
    path = tmp_path / "engine.json"
    assert main(["bench", "engine", "--trials", "2", "--sweep", "3-4", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["single_run"]["robots"] == 6 and result["single_run"]["steps"] == 3000  # control.max_steps
    assert result["single_run"]["steps_per_s"] > 0
    protocol = result["protocol_alone"]  # the six robot protocols in one process: 12 messages a step, 4 per poll
    assert protocol["robots"] == 6 and protocol["steps"] == 1000 and protocol["steps_per_s"] > 0
    extra = round(protocol["messages_per_step"] * 1000) - 12 * 1000
    assert extra > 0 and extra % 4 == 0
    assert {key: result["experiment_n6"][key] for key in ("trials", "runs", "converged")} == \
        {"trials": 2, "runs": 4, "converged": 4}
    assert {key: result["sweep"][key] for key in ("robots", "runs", "converged")} == \
        {"robots": "3..4", "runs": 8, "converged": 8}


def test_bench_engine_shows_its_progress_on_a_terminal_only() -> None:
    terminal = Console(file=io.StringIO(), record=True, width=100, force_terminal=True, color_system=None)
    results = engine_results(1, [3], console=terminal)
    shown = terminal.export_text()
    assert results["sweep"]["runs"] == 2
    # One bar per part, each complete at the end (in batch-steps: batches x control.max_steps).
    for label, total in (("one run, N = 6", 3000), ("experiment N = 6, 1 trials x 2", 6000),
                         ("sweep N = 3..3, 1 trials x 2", 6000)):
        assert re.search(rf"{re.escape(label)} .* {total}/{total}", shown), shown
    piped = Console(file=io.StringIO(), record=True, width=100, force_terminal=False)
    progress = EngineProgress(3000, piped)  # what engine_results draws, fed the same way
    with progress.bar:
        progress.part("one run, N = 6", 1)
        for step in range(1, 3001):
            progress.on_step(6, "self", step)
        progress.close()
    assert piped.export_text() == ""


def test_suite_ratios_are_steps_in_the_runs_own_round_trips() -> None:
    def row(robots: int, per_process: int, steps_per_s: float, rss: float) -> dict:
        return {"robots": robots, "robots_per_process": per_process, "steps_per_s": steps_per_s,
                "startup_s": 2.5, "robot_process_rss_mib": rss}

    results = {"latency": {"median_us": 250.0},
               "engine": {"protocol_alone": {"steps_per_s": 800.0}},
               "emulator": [row(6, 1, 100.0, 45.0), row(64, 1, 8.0, 46.0), row(64, 16, 20.0, 52.0)]}
    ratios = suite_ratios(results)
    assert ratios["round_trips_per_step"] == {"6x1": 40.0, "64x1": 500.0, "64x16": 200.0}  # 1 / (steps/s x 250 us)
    assert ratios["protocol_alone_round_trips_per_step"] == 5.0
    assert ratios["startup_64_s"] == 2.5
    assert ratios["robot_process_rss_mib_1_per_process"] == 46.0
    assert ratios["robot_process_rss_mib_16_per_process"] == 52.0


@pytest.mark.processes
def test_studies_bench_quick_reports_every_measurement(tmp_path: Path) -> None:
    """``bench studies --quick`` measures everything it reports (positive numbers); its targets are
    shown beside the values, never asserted."""
    path = tmp_path / "studies.json"
    assert main(["bench", "studies", "--quick", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert set(result["throughput_trials_per_s"]) == {"stationary_n6_self", "moving_decentralized_self",
                                                      "moving_decentralized_belief", "moving_centralized_self"}
    cores = result["machine"]["cores"]
    for rates in result["throughput_trials_per_s"].values():
        assert set(rates) == {"workers_1", f"workers_{cores}"}
        assert all(isinstance(rate, float) and rate > 0 for rate in rates.values())
    measured = ["alone_s_per_trial", "batch_10_s_per_trial", "batch_100_s_per_trial", "decentralized_over_centralized",
                "faults_study_s", "stationary_sweep_s", "workers_2_speedup", "two_process_ceiling"]
    assert all(isinstance(result[name], float) and result[name] > 0 for name in measured)
    batched = result["decentralized_over_centralized_batched"]
    assert set(batched) == {"batch_10", "batch_100"} and all(ratio > 0 for ratio in batched.values())


LOCK_HELD_S = 0.2  # s: how long a lock-holding task holds the lock (below)


def sleep_a_while(lock: Path) -> None:
    """A task that takes LOCK_HELD_S without the CPU: any number run at once."""
    time.sleep(LOCK_HELD_S)


def hold_the_lock(lock: Path) -> None:
    """A task that takes LOCK_HELD_S holding an exclusive lock on ``lock``: two copies run one after
    the other, however many processes run them."""
    with lock.open("w") as file:
        fcntl.flock(file, fcntl.LOCK_EX)
        time.sleep(LOCK_HELD_S)


@pytest.mark.processes
def test_the_two_process_ceiling_is_two_for_tasks_that_share_nothing_and_one_for_tasks_that_queue(
        tmp_path: Path) -> None:
    """The most two processes gain: about 2 for tasks that do not compete (sleeps), about 1 for
    tasks that take turns on one resource (a lock); a machine's cores are in between."""
    lock = tmp_path / "lock"
    assert 1.5 < two_process_ceiling(sleep_a_while, lock, 3) <= 2.2
    assert 0.6 < two_process_ceiling(hold_the_lock, lock, 3) < 1.3
