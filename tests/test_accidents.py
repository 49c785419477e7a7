"""Faults a user causes by accident: output locations that cannot be written, a disk that fills
during a run. Each gets one line naming the file and why, never a traceback, and no work is done
before every output location has been checked."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from ringtrack.tools.output.files import OutputError, write_csv, write_json
from ringtrack.tools.runlog.log import LogWriteError, LogWriter, read_log
from tests.helpers import RINGTRACK, processes_mentioning


def ringtrack(*arguments: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*RINGTRACK, *arguments], capture_output=True, text=True, cwd=cwd, timeout=timeout)


def one_line_error(result: subprocess.CompletedProcess[str]) -> str:
    """The single stderr line of a command that failed cleanly (no traceback)."""
    lines = result.stderr.strip().splitlines()
    assert "Traceback" not in result.stderr, result.stderr
    assert len(lines) == 1, result.stderr
    return lines[0]


@contextlib.contextmanager
def mounted_tmpfs(folder: Path, options: str) -> Iterator[Path]:
    """A tmpfs mounted at ``folder`` with ``options`` (e.g. ``size=128k`` or ``ro``); skips the
    test when this process may not mount (not root, or no CAP_SYS_ADMIN in a container)."""
    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs to fill or freeze a disk needs root")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], capture_output=True,
                             text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


@pytest.mark.processes
def test_spawn_into_a_file_says_so_in_one_line(tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("")
    result = ringtrack("spawn", "--runs", str(afile), "--no-dashboard")
    assert result.returncode == 2
    assert one_line_error(result) == (f"ringtrack: error: --runs {afile}: cannot make a run folder there (it is not "
                                      "a folder); give a writable folder with --runs DIR")


@pytest.mark.processes
def test_spawn_on_a_read_only_file_system_says_so_before_starting(tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "ro", "ro,size=64k") as readonly:
        explicit = ringtrack("spawn", "--runs", str(readonly / "runs"), "--no-dashboard")
        from_cwd = ringtrack("spawn", "--no-dashboard", cwd=readonly)  # default --runs runs, under the cwd
    for result, runs in ((explicit, readonly / "runs"), (from_cwd, Path("runs"))):
        assert result.returncode == 2
        assert one_line_error(result) == (f"ringtrack: error: --runs {runs}: cannot make a run folder there "
                                          "(Read-only file system); give a writable folder with --runs DIR")


@pytest.mark.processes
@pytest.mark.parametrize("command", ["simulate", "spawn"])
def test_a_log_path_that_cannot_be_written_is_refused_before_any_work(command: str, tmp_path: Path) -> None:
    result = ringtrack(command, "--log", "/proc/run.jsonl", "--runs", str(tmp_path / "runs"), *(
        ["--no-dashboard"] if command == "spawn" else []))
    assert result.returncode == 2
    assert one_line_error(result) == (f"ringtrack: error: argument --log: '/proc/run.jsonl': cannot write there (No "
                                      f"such file or directory); give a writable path (see 'ringtrack {command} "
                                      "--help')")
    assert result.stdout == ""  # nothing was simulated
    assert not (tmp_path / "runs").exists()  # no run folder, no process started


@pytest.mark.processes
def test_simulate_log_on_a_full_disk_is_one_line(tmp_path: Path) -> None:
    full = tmp_path / "full.jsonl"
    full.symlink_to("/dev/full")
    result = ringtrack("simulate", "--steps", "5", "--log", str(full))
    assert result.returncode == 3  # the run log could not be written
    assert one_line_error(result) == (f"ringtrack: error: {full}: cannot write the run log (No space left on "
                                      "device); it holds 0 complete steps")


@pytest.mark.processes
def test_a_full_disk_cuts_the_log_back_to_its_last_complete_record(tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "small", "size=16k") as small:
        path = small / "log.jsonl"
        writer = LogWriter(path)
        record = {"type": "step", "padding": "x" * 1000}
        with pytest.raises(LogWriteError) as raised:
            for _ in range(100):
                writer.write(record)
        written = writer.steps_written
        assert 0 < written < 100
        assert str(raised.value) == (f"{path}: cannot write the run log (No space left on device); it holds "
                                     f"{written} complete steps")
        lines = path.read_bytes().split(b"\n")
        assert lines[-1] == b"" and len(lines) == written + 1  # every line complete, none torn
        with pytest.raises(LogWriteError):
            writer.write(record)  # refused after the failure
        writer.close()


@pytest.mark.processes
def test_a_team_on_a_disk_that_fills_stops_and_says_what_it_does_not_know(tmp_path: Path) -> None:
    """The run folder's disk fills during the run: spawn stops the team (exit code 1), leaves a log
    of whole records and no partial file, and does not report a traffic total nobody counted."""
    with mounted_tmpfs(tmp_path / "small", "size=150k") as small:
        result = ringtrack("spawn", "--runs", str(small), "--no-dashboard")
        (folder,) = small.iterdir()
        leftovers = sorted(path.name for path in folder.iterdir() if path.name.endswith(".partial"))
        log = read_log(folder / "log.jsonl")
        assert processes_mentioning(str(folder)) == []
    assert result.returncode == 1 and "Traceback" not in result.stderr
    assert leftovers == []
    assert log.steps and log.end is None
    summary = result.stdout.strip().splitlines()[-2]
    assert summary.startswith(f"spawn: {len(log.steps)} steps; did not converge; robot-to-robot messages unknown "
                              "(the monitor was lost and ")


@pytest.mark.processes
def test_summary_json_is_written_whole_or_not_at_all(tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "small", "size=8k") as small:
        target = small / "summary.json"
        with pytest.raises(OutputError) as raised:
            write_json(target, {"padding": "x" * 20000})
        assert str(raised.value) == f"{target}: not written (No space left on device)"
        assert list(small.iterdir()) == []  # neither a 0-byte summary nor a leftover temporary file
        write_json(target, {"small": 1})
        assert json.loads(target.read_text()) == {"small": 1}


@pytest.mark.processes
def test_csv_is_written_whole_or_not_at_all(tmp_path: Path) -> None:
    """A table that fails halfway (a full disk, or its rows raise) leaves no file and no temporary."""
    with mounted_tmpfs(tmp_path / "small", "size=8k") as small:
        target = small / "rows.csv"
        with pytest.raises(OutputError) as raised:
            write_csv(target, ({"a": "x" * 100} for _ in range(200)), ["a"])
        assert str(raised.value) == f"{target}: not written (No space left on device)"
        assert list(small.iterdir()) == []

    def failing() -> Iterator[dict]:
        yield {"a": 1}
        raise RuntimeError("the study broke")

    with pytest.raises(RuntimeError):
        write_csv(tmp_path / "rows.csv", failing(), ["a"])
    assert [path.name for path in tmp_path.iterdir() if path.name.startswith((".rows", "rows"))] == []
    assert write_csv(tmp_path / "rows.csv", [{"a": 1, "b": "x"}, {"a": None, "b": "y"}], ["a", "b"]) == 2
    assert (tmp_path / "rows.csv").read_text().splitlines() == ["a,b", "1,x", ",y"]


@pytest.mark.processes
def test_a_disk_that_fills_during_a_spawn_stops_the_team_in_one_line(tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "small", "size=96k") as small:
        result = ringtrack("spawn", "--runs", str(small), "--no-dashboard", timeout=180)
        folders = list(small.iterdir())
        assert len(folders) == 1
        log = read_log(folders[0] / "log.jsonl")  # readable up to the last complete step
        assert "Traceback" not in result.stderr, result.stderr
        assert result.returncode == 1
        steps = len(log.steps)
        assert 0 < steps < 712 and log.end is None
        assert [step["step"] for step in log.steps] == list(range(1, steps + 1))
        line = (f"ringtrack: error: {folders[0] / 'log.jsonl'}: the run log could not be written (disk full or not "
                f"writable) after {steps} complete steps; the team was stopped")
        assert line in result.stderr.splitlines(), result.stderr
        assert "exited with" not in result.stderr  # the processes the supervisor stopped did not crash
        summary = folders[0] / "summary.json"
        if summary.exists():  # written whole, or not at all and said why
            assert json.loads(summary.read_text())["exit_code"] == 1
        else:
            assert f"ringtrack: error: {summary}: not written (No space left on device)" in result.stderr
    assert processes_mentioning(str(small)) == []
