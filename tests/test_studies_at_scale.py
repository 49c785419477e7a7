"""Studies at scale (tools/studies/): the same bytes from one process, a pool of workers
and a Dask cluster; a journal that survives a kill and a ``--resume`` that runs only what it lacks;
progress in trials."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest
from rich.console import Console

from ringtrack.tools.cli import main
from ringtrack.tools.output.progress import TrialProgress, duration
from ringtrack.tools.studies import pool, provenance, runner
from ringtrack.tools.studies.experiment import STATIONARY_BATCH, StationaryPart, StationaryTask, stationary_task
from ringtrack.tools.studies.journal import inputs_digest
from ringtrack.tools.studies.provenance import PACKAGE_ROOT, RESULT_SOURCES
from ringtrack.tools.studies.study import BATCH, Execution, Study, StudyStopped, Task
from ringtrack.world.scenario import load_scenario
from tests.helpers import MOVING, RINGTRACK
from tests.test_strategy import example

# Small studies of several tasks each (--batch 2), one per experiment command.
STUDIES = {
    "stationary": ["experiment", "stationary", "--robots", "4", "--trials", "3", "--batch", "2"],
    "moving": ["experiment", "moving", "authors-moving", "--no-velocities", "--trials", "3", "--steps", "100",
               "--settle", "20", "--batch", "2"],
    "faults": ["experiment", "faults", "--drop", "0,0.3", "--trials", "3", "--steps", "400", "--batch", "2"],
    "gates": ["experiment", "gates", "--gates", "1,2", "--trials", "3", "--steps", "100", "--settle", "20",
              "--batch", "2"],
    "tracking": ["experiment", "tracking", "authors-moving", "--strategies", "self,belief", "--trials", "3", "--steps",
                 "100", "--settle", "20", "--batch", "2"],
}
WALL = re.compile(rb'\n *"wall_s": [^\n]*')


def without_wall(path: Path) -> bytes:
    """The JSON file's bytes but its wall-clock lines (``wall_s``)."""
    return WALL.sub(b"", path.read_bytes())


def run(arguments: list[str], folder: Path, name: str, *more: str) -> tuple[bytes, bytes | None]:
    """Run the study in-process writing ``folder/name.json`` (and ``.csv`` where the command has
    one); its JSON without wall-clock lines and its CSV bytes."""
    json_path, csv_path = folder / f"{name}.json", folder / f"{name}.csv"
    outputs = ["--json", str(json_path)] + ([] if "gates" in arguments else ["--csv", str(csv_path)])
    assert main([*arguments, *outputs, *more]) == 0
    return without_wall(json_path), csv_path.read_bytes() if csv_path.exists() else None


@pytest.mark.processes
@pytest.mark.parametrize("study", sorted(STUDIES))
def test_two_workers_write_the_bytes_of_one(study: str, tmp_path: Path) -> None:
    one = run(STUDIES[study], tmp_path, "one", "--workers", "1", "--quiet")
    two = run(STUDIES[study], tmp_path, "two", "--workers", "2", "--quiet")
    assert one == two
    assert b'"rows"' in one[0] or b'"points"' in one[0]


@pytest.mark.parametrize("study", sorted(STUDIES))
def test_batching_does_not_change_a_study(study: str, tmp_path: Path) -> None:
    """Trials in batches of 2 or all in one: the same bytes (a trial's history does not depend on its
    batch, and trials are added up exactly)."""
    assert STUDIES[study][-2:] == ["--batch", "2"]
    arguments = STUDIES[study][:-2]
    pairs = run([*arguments, "--batch", "2"], tmp_path, "pairs", "--workers", "1", "--quiet")
    whole = run([*arguments, "--batch", "3"], tmp_path, "whole", "--workers", "1", "--quiet")
    assert pairs == whole


@pytest.mark.parametrize(("study", "run_name"), [("moving", "a run"), ("faults", "a run"), ("gates", "a run"),
                                               ("tracking", "authors-moving")])
def test_a_settle_past_the_run_gets_one_line(study: str, run_name: str, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Every study that averages from --settle on refuses one that leaves no step (the gates study
    crashed on its empty means), before it runs or writes anything."""
    command = ["experiment", study, "authors-moving", "--trials", "1", "--steps", "80", "--settle", "80"]
    assert main([*command, "--json", str(tmp_path / "s.json"), "--workers", "1", "--quiet"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"ringtrack: error: --settle 80: must be below the 80 steps of {run_name}"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("arguments", "error"), [
    (["gates", "paper-stationary", "--gates", "1"],
     "paper-stationary: experiment gates needs a moving target (target.motion = 'circle', 'random_walk' or "
     "'waypoints'); give a moving scenario such as authors-moving"),
    (["moving", "--strategies", "self,plan"],
     "--strategies: the plan strategy needs estimation.mode = 'known', and a moving target's runs estimate it "
     "(centralized or decentralized); leave it out"),
    (["moving", "authors-moving"],
     "the velocity setting v = 1 m/s, w = 0.4 rad/s puts the target of authors-moving on a circle of radius 2.5 m "
     "that leaves the region; give --no-velocities to run the scenario's own circle only"),
    (["stationary", "--strategies", "self,belief"],
     "--strategies: the belief strategy needs estimation.mode = 'decentralized' and paper-stationary has 'known'; "
     "give a scenario with estimation.mode = 'decentralized', or compare it with experiment moving or tracking"),
    (["stationary", "--sigma-deg", "-1"], "--sigma-deg -1.0 (control.sigma_deg): expected a finite number >= 0; "
                                          "fix the value"),
], ids=["gates-stationary", "moving-plan", "moving-velocity-off-region", "stationary-belief", "stationary-sigma"])
def test_a_study_it_cannot_run_gets_one_line(arguments: list[str], error: str, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """What a study cannot run is refused before it runs, in one line naming the fix (each of these
    ended in a traceback, ran without the strategy, or named a flag the command does not have)."""
    command = ["experiment", *arguments, "--trials", "1", "--steps", "20", "--json", str(tmp_path / "s.json")]
    settle = ["--settle", "0"] if arguments[0] in ("gates", "moving") else []
    assert main([*command, *settle, "--workers", "1", "--quiet"]) == 2
    assert capsys.readouterr().err.splitlines() == [f"ringtrack: error: {error}"]
    assert list(tmp_path.iterdir()) == []


@contextlib.contextmanager
def local_cluster(workers: int, **config: object) -> Iterator[str]:
    """A Dask LocalCluster of ``workers`` single-threaded worker processes, its scheduler's HTTP
    server too on loopback only, under Dask ``config``: its address."""
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("dask.distributed")
    with (dask.config.set(config),
          distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address="127.0.0.1:0") as local):
        yield local.scheduler_address


@pytest.fixture(scope="module")
def cluster() -> Iterator[str]:
    """A cluster of two workers for the module's tests: its address."""
    with local_cluster(2) as address:
        yield address


@pytest.mark.processes
def test_a_dask_cluster_writes_the_bytes_of_one_process(cluster: str, tmp_path: Path) -> None:
    local = run(STUDIES["moving"], tmp_path, "local", "--workers", "1", "--quiet")
    remote = run(STUDIES["moving"], tmp_path, "remote", "--cluster", cluster, "--quiet")
    assert local == remote


def test_cluster_without_dask_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import dask.distributed raises ImportError
    assert main([*STUDIES["stationary"], "--cluster", "tcp://127.0.0.1:1", "--json", str(tmp_path / "s.json")]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "ringtrack: error: --cluster needs Dask: pip install 'ringtrack[cluster]'"]
    assert not (tmp_path / "s.journal.jsonl").exists()


def counted_tasks(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The keys of the tasks this process runs from now on (the runner's in-process path)."""
    keys: list[str] = []
    execute = provenance.execute

    def counting(work, task):  # type: ignore[no-untyped-def]
        keys.append(task.key)
        return execute(work, task)

    monkeypatch.setattr(provenance, "execute", counting)
    return keys


def test_resume_after_a_torn_journal_runs_only_the_missing_tasks(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    arguments = [*STUDIES["moving"], "--workers", "1", "--quiet"]
    whole = run(arguments, tmp_path, "whole")
    journal = tmp_path / "whole.journal.jsonl"
    lines = journal.read_bytes().splitlines(keepends=True)
    assert len(lines) == 1 + 6  # the header and 3 runs x 2 chunks
    journal.write_bytes(b"".join(lines[:3]) + lines[3][: len(lines[3]) // 2])  # killed while writing task 3
    (tmp_path / "whole.json").unlink()
    keys = counted_tasks(monkeypatch)
    assert run(arguments, tmp_path, "whole", "--resume") == whole
    assert len(keys) == 4 and "2 of 6 tasks done, 4 to run" in capsys.readouterr().err
    assert journal.read_bytes().splitlines(keepends=True)[:3] == lines[:3]
    assert len(journal.read_bytes().splitlines()) == 7


def journalled_a_task(child: subprocess.Popen, journal: Path, also: Callable[[], bool] = lambda: True,
                      timeout_s: float = 120) -> None:
    """Wait until ``child``'s study has journalled a task (its header and a task line) and ``also()``
    holds, or the study ended, or ``timeout_s`` passed (a hang guard: the caller asserts the rest)."""
    deadline = time.monotonic() + timeout_s
    while child.poll() is None and time.monotonic() < deadline:
        if journal.exists() and journal.read_bytes().count(b"\n") >= 2 and also():
            return
        time.sleep(0.05)


@pytest.mark.processes
def test_a_study_killed_mid_way_resumes_to_the_bytes_of_an_uninterrupted_one(monkeypatch: pytest.MonkeyPatch,
                                                                              tmp_path: Path) -> None:
    arguments = ["experiment", "moving", "authors-moving", "--no-velocities", "--trials", "4", "--steps", "100",
                 "--settle", "20", "--batch", "1", "--workers", "1", "--quiet"]
    output, journal = tmp_path / "killed.json", tmp_path / "killed.journal.jsonl"
    child = subprocess.Popen([*RINGTRACK, *arguments, "--json", str(output)], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    try:
        journalled_a_task(child, journal)
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait(timeout=30)
    finished = journal.read_bytes().count(b"\n") - 1
    assert not output.exists() and 1 <= finished < 12
    keys = counted_tasks(monkeypatch)
    resumed = run(arguments, tmp_path, "killed", "--resume")
    assert len(keys) == 12 - finished and len(set(keys)) == len(keys)
    assert resumed == run(arguments, tmp_path, "whole")


def test_resume_without_a_journal_or_with_another_studys(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    arguments = [*STUDIES["stationary"], "--workers", "1", "--quiet", "--json", str(tmp_path / "s.json")]
    assert main([*arguments, "--resume"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"ringtrack: error: --resume: no journal at {tmp_path / 's.journal.jsonl'}; run without --resume to start "
        "the study"]
    assert main(arguments) == 0
    assert main([*arguments, "--resume", "--trials", "4"]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"ringtrack: error: --resume: {tmp_path / 's.journal.jsonl'} is the journal of another study (trials 3 there, "
        "4 here); give the same flags or run without --resume to start over")
    assert main(arguments) == 0
    assert capsys.readouterr().err.splitlines() == [
        f"experiment stationary: replacing the journal {tmp_path / 's.journal.jsonl'} (--resume continues one)"]


def test_resume_with_the_default_batch_given_is_the_same_study(tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A study started with the default --batch resumes with that number given, and the other way:
    the journal keeps the trials per task the study was cut into, not whether a flag said it."""
    for study, default in (("stationary", STATIONARY_BATCH), ("moving", BATCH)):
        arguments = [*STUDIES[study][:-2], "--workers", "1", "--quiet", "--json", str(tmp_path / f"{study}.json")]
        assert main(arguments) == 0
        assert main([*arguments, "--resume", "--batch", str(default)]) == 0
        assert capsys.readouterr().err.splitlines()[-1].endswith("tasks done, 0 to run")
        assert main([*arguments, "--batch", str(default)]) == 0
        assert main([*arguments, "--resume"]) == 0
        assert capsys.readouterr().err.splitlines()[-1].endswith("tasks done, 0 to run")


def test_resume_refuses_a_journal_of_other_code_or_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A journal records a digest of the code that computes results and of the files the study reads:
    resuming after either changed would mix two studies' trials, so ``--resume`` refuses."""
    scenario = tmp_path / "square.toml"
    scenario.write_bytes((PACKAGE_ROOT / "scenarios" / "paper-stationary.toml").read_bytes())
    journal = tmp_path / "s.journal.jsonl"
    arguments = ["experiment", "stationary", str(scenario), "--robots", "4", "--trials", "3", "--batch", "2",
                 "--workers", "1", "--quiet", "--json", str(tmp_path / "s.json")]
    refused = (f"ringtrack: error: --resume: {journal} was written by other code or from other files (ringtrack's "
               "source or a file the study reads has changed since); finish it with what began it, or run without "
               "--resume to start over")
    assert main(arguments) == 0
    header, *tasks = journal.read_bytes().splitlines(keepends=True)
    assert main([*arguments, "--resume"]) == 0  # nothing changed: resumed (nothing left to run)
    scenario.write_bytes(scenario.read_bytes() + b"\n# a comment changes the file\n")
    assert main([*arguments, "--resume"]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == refused
    assert main(arguments) == 0  # started over from the edited file
    header, *tasks = journal.read_bytes().splitlines(keepends=True)
    decoded = json.loads(header)
    assert decoded["inputs"] == inputs_digest(decoded["parameters"])
    del decoded["inputs"]  # a journal from before the digest was kept: whatever computed it is unknown
    journal.write_bytes(json.dumps(decoded).encode() + b"\n" + b"".join(tasks))
    assert main([*arguments, "--resume"]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == refused


def test_resume_refuses_a_journal_whose_scenario_names_an_edited_strategy_file(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A strategy file that a scenario file names (rather than the command) is read by the study's
    tasks too: edited between a run and its ``--resume``, the journal is refused, as when the scenario
    file itself is edited (before, the study resumed and mixed the trials of both versions)."""
    monkeypatch.chdir(tmp_path)
    strategy = example(tmp_path)
    (tmp_path / "mine.toml").write_text(MOVING.replace('[strategy]\nname = "self"', f'[strategy]\nname = "{strategy.name}"'))
    journal = tmp_path / "t.journal.jsonl"
    arguments = ["experiment", "tracking", "mine.toml", "--strategies", "self", "--trials", "2", "--steps", "60",
                 "--settle", "10", "--batch", "1", "--workers", "1", "--quiet", "--json", "t.json"]
    assert main(arguments) == 0
    whole = journal.read_bytes()
    journal.write_bytes(whole[: whole.rstrip(b"\n").rfind(b"\n") + 1])  # the last task lost
    strategy.write_bytes(strategy.read_bytes() + b"\n# edited\n")
    assert main([*arguments, "--resume"]) == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith(
        f"ringtrack: error: --resume: {journal.name} was written by other code or from other files")


def test_inputs_digest_covers_the_code_and_the_named_files(tmp_path: Path) -> None:
    strategy = tmp_path / "mine.py"
    strategy.write_text("x = 1\n")
    parameters = {"scenario": "paper-stationary", "strategies": ["self", str(strategy)]}
    digest = inputs_digest(parameters)
    assert inputs_digest(parameters) == digest and len(digest) == 64
    assert inputs_digest({"scenario": "paper-stationary", "strategies": ["self"]}) != digest
    strategy.write_text("x = 2\n")
    assert inputs_digest(parameters) != digest
    assert {"agents", "bus", "world", "scenarios"} <= set(RESULT_SOURCES)


def test_pools_and_clusters_get_the_costliest_tasks_first() -> None:
    """A sweep's large teams start first (a long task started last would run alone at the end); tasks
    of equal cost keep the study's order."""
    tasks = [StationaryTask(f"N={robots} {strategy}", 0, seeds, strategy,
                            [load_scenario("paper-stationary", robots=robots)] * len(seeds), list(range(len(seeds))))
             for robots, seeds in ((3, [0, 1]), (30, [0, 1]), (6, [0, 1]), (30, [2])) for strategy in ("constant", "self")]
    study = Study("stationary", {}, tasks, stationary_task, StationaryPart)
    order = runner.costliest_first(study, [0, 1, 2, 3, 4, 5, 7])
    assert [tasks[index].key for index in order] == ["N=30 constant", "N=30 self", "N=30 self", "N=6 constant",
                                                     "N=6 self", "N=3 constant", "N=3 self"]
    assert order == [2, 3, 7, 4, 5, 0, 1]


def test_progress_off_a_terminal_is_plain_lines_and_quiet_is_nothing() -> None:
    piped = Console(file=io.StringIO(), force_terminal=False, width=60)
    with TrialProgress("experiment moving", 120, console=piped, every_s=0.0) as progress:
        progress.advance(40)
        progress.advance(80)
    lines = piped.file.getvalue().splitlines()  # type: ignore[attr-defined]
    assert re.fullmatch(r"experiment moving: 40/120 trials, 33%, eta \d+s", lines[0])
    assert lines[1:] == ["experiment moving: 120/120 trials, 100%, eta 0s"]  # the end said once
    quiet = Console(file=io.StringIO(), force_terminal=True)
    with TrialProgress("experiment moving", 10, quiet=True, console=quiet) as progress:
        progress.advance(10)
    assert quiet.file.getvalue() == ""  # type: ignore[attr-defined]
    assert [duration(seconds) for seconds in (45, 80, 3720)] == ["45s", "1m20s", "1h02m"]


class Seeds(msgspec.Struct, frozen=True):
    """What a :class:`DyingTask` returns: its seeds."""

    seeds: list[int]


@dataclass(frozen=True)
class DyingTask(Task):
    """A task whose worker dies (SIGKILL, as the out-of-memory killer does) while ``marker`` holds
    fewer than ``deaths`` bytes, adding one before it dies."""

    marker: str
    deaths: int


def die_then_answer(task: DyingTask) -> Seeds:
    """Kill this process while the task's marker holds fewer than its deaths, else return its seeds."""
    marker = Path(task.marker)
    if task.deaths and marker.stat().st_size < task.deaths:
        with marker.open("ab") as file:
            file.write(b".")
        os.kill(os.getpid(), signal.SIGKILL)
    return Seeds(task.seeds)


def dying_study(marker: Path, deaths: int) -> Study:
    """Eight tasks of one trial each; the fourth kills its worker ``deaths`` times."""
    marker.touch()
    tasks = [DyingTask(f"task {index}", index, [index], str(marker), deaths if index == 3 else 0)
             for index in range(8)]
    return Study("dying", {}, tasks, die_then_answer, Seeds)


@pytest.mark.processes
def test_the_tasks_of_a_worker_that_died_run_again_in_a_new_pool(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    results = runner.run_study(dying_study(tmp_path / "marker", 2), Execution(workers=2))
    assert results == [Seeds([index]) for index in range(8)]
    notes = [line for line in capsys.readouterr().err.splitlines() if "died" in line]
    assert len(notes) == 2 and notes[0].startswith("experiment dying: a worker process died (killed, or out of "
                                                   "memory); running its pool's ")
    assert notes[1].endswith(f"in a new pool (2 of {pool.POOL_RESTARTS})")


@pytest.mark.processes
def test_a_task_that_keeps_killing_its_worker_ends_the_study_in_one_line(tmp_path: Path) -> None:
    journal = tmp_path / "s.journal.jsonl"
    with pytest.raises(StudyStopped) as raised:
        runner.run_study(dying_study(tmp_path / "marker", 99), Execution(workers=2, journal=journal))
    assert str(raised.value) == (
        f"experiment dying: a worker process died {pool.POOL_RESTARTS + 1} times (killed, or out of memory: try "
        f"fewer --workers or a smaller --batch); its finished tasks are kept in {journal}: run the same command "
        "with --resume to continue")
    assert StudyStopped.exit_code == 1


@pytest.mark.processes
def test_a_task_that_keeps_killing_its_dask_workers_ends_the_study_in_one_line(tmp_path: Path) -> None:
    """The scheduler gives up on a task after ``allowed-failures`` deaths of its workers (here 1)."""
    with (local_cluster(1, **{"distributed.scheduler.allowed-failures": 1}) as address,
          pytest.raises(StudyStopped) as raised):
        runner.run_study(dying_study(tmp_path / "marker", 99), Execution(cluster=address))
    assert (tmp_path / "marker").stat().st_size == 2  # it died twice, the second time for good
    assert str(raised.value) == (
        "experiment dying: the workers that ran task 'task 3' kept dying (killed, or out of memory); its finished "
        "tasks are not kept (give --json or --csv: their journal keeps them for --resume)")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full (a device whose writes find the disk full)")
def test_a_journal_on_a_full_disk_stops_the_study_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    journal = tmp_path / "s.journal.jsonl"
    journal.symlink_to("/dev/full")
    assert main([*STUDIES["stationary"], "--workers", "1", "--quiet", "--json", str(tmp_path / "s.json")]) == 1
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"ringtrack: error: {journal}: not written (No space left on device); the study's finished tasks are kept "
        "there: make room and run it again with --resume")
    assert not (tmp_path / "s.json").exists()


def descendants(pid: int) -> set[int]:
    """The pids of every process below ``pid`` (its children's children too), from /proc."""
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            for child in map(int, (task / "children").read_text().split()):
                found |= {child, *descendants(child)}
    return found


@pytest.mark.processes
@pytest.mark.parametrize(("stop", "code", "line"), [(signal.SIGTERM, 143, "ringtrack: terminated (SIGTERM)"),
                                                    (signal.SIGINT, 130, "ringtrack: interrupted"),
                                                    (signal.SIGKILL, -9, None)])
def test_a_signal_to_a_study_ends_its_workers_and_keeps_its_journal(stop: signal.Signals, code: int, line: str | None,
                                                                   tmp_path: Path) -> None:
    """SIGTERM (a batch system, systemd, docker stop), SIGINT or SIGKILL (the out-of-memory killer,
    ``kill -9``) to the study's process alone: its workers, the fork server and multiprocessing's
    resource tracker end with it, whatever they were running (after a SIGKILL they were left waiting
    for tasks for ever), and the journal holds whole lines only."""
    output, journal = tmp_path / "s.json", tmp_path / "s.journal.jsonl"
    child = subprocess.Popen([*RINGTRACK, "experiment", "stationary", "--robots", "8-12", "--trials", "40", "--batch",
                              "5", "--workers", "2", "--quiet", "--json", str(output)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    workers: set[int] = set()

    def all_started() -> bool:  # the fork server and 2 workers
        workers.update(descendants(child.pid))
        return len(workers) >= 3

    try:
        journalled_a_task(child, journal, all_started)
        assert len(workers) >= 3
        child.send_signal(stop)
        _, errors = child.communicate(timeout=60)
        deadline = time.monotonic() + 30
        while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        left = [pid for pid in workers if Path(f"/proc/{pid}").exists()]
    finally:
        child.kill()
        child.wait()
        for pid in workers:  # whatever the study left, ended here (they are this test's)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    assert child.returncode == code and (line is None or errors.splitlines()[-1] == line)
    assert not left
    assert not output.exists() and journal.read_bytes().endswith(b"\n")


@pytest.mark.parametrize("resume", [False, True])
def test_a_journal_another_study_is_writing_is_left_alone(resume: bool, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The same command started twice: the second refuses in one line, and neither replaces nor
    continues the first's journal."""
    arguments = [*STUDIES["stationary"], "--workers", "1", "--quiet", "--json", str(tmp_path / "s.json")]
    assert main(arguments) == 0
    journal = tmp_path / "s.journal.jsonl"
    written = journal.read_bytes()
    capsys.readouterr()
    with journal.open("rb") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # as the first study holds it while it runs
        assert main([*arguments, *(["--resume"] if resume else [])]) == 2
    assert capsys.readouterr().err.splitlines() == [  # nothing said of resuming or replacing it
        f"ringtrack: error: {journal}: another study is writing this journal (the same command running elsewhere?); "
        "wait for it to end, or give another --json or --csv"]
    assert journal.read_bytes() == written


def test_a_journal_where_files_cannot_be_locked_is_written_unguarded(monkeypatch: pytest.MonkeyPatch,
                                                                     tmp_path: Path) -> None:
    """Some network and FUSE file systems refuse locks (ENOLCK): the study runs, its journal whole."""

    def refuse(file: object, operation: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", refuse)
    assert main([*STUDIES["stationary"], "--workers", "1", "--quiet", "--json", str(tmp_path / "s.json")]) == 0
    assert len((tmp_path / "s.journal.jsonl").read_bytes().splitlines()) == 1 + 4  # header, 2 strategies x 2 chunks
