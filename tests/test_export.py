"""CSV tables of a run (``ringtrack export``, tools/runlog/export.py) and of the experiments (``--csv``),
read back with the csv module against the log and the results they came from."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from ringtrack.tools.cli import main
from ringtrack.tools.runlog.export import LINK_COLUMNS, STEP_COLUMNS
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.studies.experiment import MOVING_COLUMNS
from ringtrack.world.geometry import angle_of


def rows_of(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as file:
        reader = csv.DictReader(file)
        return list(reader.fieldnames or []), list(reader)


def test_export_of_an_engine_log_holds_every_step_and_robot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log_path, tables = tmp_path / "run.jsonl", tmp_path / "tables"
    assert main(["simulate", "authors-moving", "--estimation", "decentralized", "--steps", "25",
                 "--log", str(log_path)]) == 0
    assert main(["export", str(log_path), "--csv", str(tables)]) == 0
    assert f"wrote {tables / 'steps.csv'} (150 rows)" in capsys.readouterr().out
    log = read_log(log_path)
    header, rows = rows_of(tables / "steps.csv")
    assert header == STEP_COLUMNS and len(rows) == 25 * 6
    for row in rows:
        record = log.steps[int(row["step"]) - 1]
        robot = int(row["robot"])
        assert float(row["time_s"]) == record["time"] and int(row["live"]) == 1
        assert [float(row["x_m"]), float(row["y_m"])] == record["positions"][robot]
        assert math.isclose(float(row["offset_deg"]), math.degrees(record["offset"][robot]))
        centre = record["centre"][robot]
        assert math.isclose(float(row["angle_deg"]), math.degrees(float(angle_of(record["positions"][robot], centre)))
                            % 360.0)
        assert int(row["trigger"]) == record["trigger"][robot]
        assert [int(row["age_pred_steps"]), int(row["age_succ_steps"])] == record["ages"][robot]
        assert int(row["sent_messages"]) == record["sent_messages"][robot] and row["sent_bytes"] == ""  # engine: none
    reasons = {"start", "-", "T1", "T2", "T3", "T1+T2", "T1+T3", "T2+T3", "T1+T2+T3"}
    assert rows[0]["reasons"] == "start" and {row["reasons"] for row in rows} <= reasons
    header, links = rows_of(tables / "links.csv")
    assert header == LINK_COLUMNS
    assert sum(int(row["messages_seen"]) for row in links) == sum(row[3] for row in log.end["traffic"])
    assert all(row["bytes_seen"] == "" for row in links)


def test_export_refuses_a_file_for_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log_path = tmp_path / "run.jsonl"
    assert main(["simulate", "--steps", "3", "--log", str(log_path)]) == 0
    assert main(["export", str(log_path), "--csv", str(log_path)]) == 2
    assert "is a file; give a folder" in capsys.readouterr().err


def test_experiment_tables(tmp_path: Path) -> None:
    stationary, results = tmp_path / "stationary.csv", tmp_path / "stationary.json"
    assert main(["experiment", "stationary", "--workers", "1", "--robots", "3,4", "--trials", "2", "--csv", str(stationary),
                 "--json", str(results)]) == 0
    import json

    expected = json.loads(results.read_text())["rows"]
    header, rows = rows_of(stationary)
    assert header[:3] == ["robots", "strategy", "trial"] and len(rows) == 2 * 2 * 2 == len(expected)
    for row, entry in zip(rows, expected, strict=True):
        assert int(row["robots"]) == entry["robots"] and row["strategy"] == entry["strategy"]
        assert int(row["ctime"]) == entry["ctime"] and float(row["com_bar"]) == entry["com_bar"]


def test_moving_experiment_table_has_a_row_per_trial(tmp_path: Path) -> None:
    moving, results = tmp_path / "moving.csv", tmp_path / "moving.json"
    assert main(["experiment", "moving", "--workers", "1", "--trials", "2", "--seed", "4", "--steps", "40", "--settle", "10",
                 "--csv", str(moving), "--json", str(results)]) == 0
    import json

    result = json.loads(results.read_text())
    header, rows = rows_of(moving)
    assert header == MOVING_COLUMNS
    # Every distinct run once (the velocity setting (1.0, 0.6) is the comparison's circle), every trial.
    runs = [("comparison", 1.0, 0.6, "constant", "centralized"), ("comparison", 1.0, 0.6, "self", "centralized"),
            ("comparison", 1.0, 0.6, "self", "decentralized")]
    runs += [("velocities", v, w, strategy, mode) for v, w in ((0.6, 0.6), (1.0, 0.4), (1.0, 0.8))
             for strategy, mode in (("constant", "centralized"), ("self", "decentralized"))]
    assert [(row["group"], float(row["speed"]), float(row["angular_speed"]), row["strategy"], row["estimation"],
             int(row["trial"]), int(row["seed"])) for row in rows] == [
        (*run, trial, 4 + trial) for run in runs for trial in (0, 1)]
    for row in rows:
        polls = float(row["polls"])
        assert float(row["robot_messages"]) == 4 * polls and 0 <= float(row["poll_rate"]) <= 1
        assert float(row["poll_rate"]) == pytest.approx(polls / (40 * 6))
        assert float(row["terr_mean"]) >= 0 and float(row["cerr_mean_deg"]) >= 0
        assert (row["fusion"] == "ci") == (row["estimation"] == "decentralized")
    # The per-run means of the table are the means of its trials.
    for run in result["runs"][:3]:
        trials = [row for row in rows if (row["group"], row["strategy"], row["estimation"]) ==
                  ("comparison", run["strategy"], run["estimation"])]
        for column in ("terr_mean", "cerr_mean_deg", "poll_rate", "polls"):
            assert sum(float(row[column]) for row in trials) / 2 == pytest.approx(run[column], rel=1e-12), column
    constant = [row for row in rows if row["strategy"] == "constant"]
    assert all(float(row["poll_rate"]) == 1.0 and int(row["estimation_messages_per_step"]) == 7 for row in constant)


def test_export_checks_its_folder_before_reading_the_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A folder under a file (or on a pseudo file system) is refused in one line before any work:
    the log is not even read (here it does not exist)."""
    inside_a_file = tmp_path / "file"
    inside_a_file.write_text("")
    assert main(["export", str(tmp_path / "missing.jsonl"), "--csv", str(inside_a_file / "tables")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"ringtrack: error: --csv {inside_a_file / 'tables'}: cannot write steps.csv there (Not a directory); "
        "give a writable folder")
    assert list(tmp_path.iterdir()) == [inside_a_file]  # nothing written, no partial file
