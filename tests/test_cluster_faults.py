"""A study on a Dask cluster meets what a cluster of several hosts meets: a scheduler that goes away
(one line, exit 1, the journal kept for ``--resume``), and workers that would compute with other
code or other files than the study's machine (they run no task; one line names the worker and what
differs). The scheduler and the workers are real ``dask`` processes started here."""

from __future__ import annotations

import contextlib
import json
import select
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from ringtrack.tools.cli import main
from ringtrack.tools.output.console import UsageError
from ringtrack.tools.studies.experiment import StationaryPart, StationaryTask, random_start_scenarios, stationary_task
from ringtrack.tools.studies.provenance import (
    PACKAGE_ROOT,
    RESULT_SOURCES,
    checked,
    execute_checked,
    origin,
    study_files,
)
from ringtrack.tools.studies.runner import run_study
from ringtrack.tools.studies.study import Execution, Study, Task, execute
from tests.helpers import RINGTRACK
from tests.test_strategy import example
from tests.test_studies_at_scale import (
    STUDIES,
    Seeds,
    counted_tasks,
    journalled_a_task,
    local_cluster,
    run,
    without_wall,
)

pytest.importorskip("dask.distributed")

# Another copy of ringtrack imported in place of this one: the editable install's finder, which
# would find this one first, is taken off the import system before the worker starts.
IMPORTING_FROM = ("import sys; sys.meta_path[:] = [finder for finder in sys.meta_path "
                  "if not getattr(finder, '__module__', '').startswith('__editable__')]; sys.path.insert(0, {folder!r}); "
                  "from distributed.cli.dask_{role} import main; main()")
STUDY = ["experiment", "stationary", "--robots", "8-12", "--trials", "6", "--batch", "2", "--quiet"]  # 30 tasks


@contextlib.contextmanager
def dask_process(role: str, *arguments: str, cwd: Path | None = None,
                 code: Path | None = None) -> Iterator[subprocess.Popen[bytes]]:
    """``dask ROLE ARGUMENTS`` (``scheduler`` or ``worker``) as a child of this test, serving on
    loopback, in folder ``cwd``; with ``code``, a folder holding another copy of ringtrack, which it
    imports instead of this one. Killed (by its pid) on leaving."""
    command = ([sys.executable, "-c", IMPORTING_FROM.format(folder=str(code), role=role)] if code is not None
               else [sys.executable, "-m", f"distributed.cli.dask_{role}"])
    child = subprocess.Popen([*command, *arguments, "--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0"],
                             cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield child
    finally:
        child.kill()
        child.wait()


def worker(address: str, cwd: Path | None = None, code: Path | None = None) -> contextlib.AbstractContextManager:
    """One single-threaded worker process (:func:`dask_process`) of the scheduler at ``address``."""
    return dask_process("worker", address, "--nthreads", "1", "--no-nanny", cwd=cwd, code=code)


def scheduler_address(scheduler_file: Path, scheduler: subprocess.Popen[bytes]) -> str:
    """The address a scheduler started with ``--scheduler-file`` serves on, once it has written it."""
    deadline = time.monotonic() + 60
    while not scheduler_file.exists() or not scheduler_file.read_bytes().strip():
        assert scheduler.poll() is None and time.monotonic() < deadline, "the scheduler did not start"
        time.sleep(0.05)
    return str(json.loads(scheduler_file.read_text())["address"])


@pytest.mark.processes
def test_a_scheduler_that_goes_away_stops_the_study_in_one_line_and_resume_finishes_it(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    output, journal, scheduler_file = tmp_path / "s.json", tmp_path / "s.journal.jsonl", tmp_path / "scheduler.json"
    with dask_process("scheduler", "--port", "0", "--scheduler-file", str(scheduler_file)) as scheduler:
        address = scheduler_address(scheduler_file, scheduler)
        with worker(address):
            study = subprocess.Popen([*RINGTRACK, *STUDY, "--cluster", address, "--json", str(output)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            try:
                journalled_a_task(study, journal)
                scheduler.kill()  # as a crash or a lost host does: no goodbye
                _, errors = study.communicate(timeout=120)
            finally:
                study.kill()
                study.wait()
    assert study.returncode == 1 and "Traceback" not in errors
    assert errors.splitlines()[-1] == (
        f"ringtrack: error: --cluster {address}: the Dask scheduler went away mid-study (lost the connection); its "
        f"finished tasks are kept in {journal}: run the same command with --resume to continue")
    finished = journal.read_bytes().count(b"\n") - 1
    assert not output.exists() and journal.read_bytes().endswith(b"\n") and 1 <= finished < 30
    keys = counted_tasks(monkeypatch)
    resumed = run(STUDY, tmp_path, "s", "--resume", "--workers", "1")
    assert len(keys) == 30 - finished
    assert resumed == run(STUDY, tmp_path, "whole", "--workers", "1")


@pytest.fixture(scope="module")
def bare_scheduler() -> Iterator[str]:
    """A scheduler with no worker of its own (each test brings its own): its address."""
    with local_cluster(0) as address:
        yield address


@pytest.mark.processes
def test_a_worker_with_other_ringtrack_code_runs_no_task(bare_scheduler: str, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The worker imports a copy of ringtrack with one line added to a file that computes results."""
    copy = tmp_path / "elsewhere" / "ringtrack"
    for part in {source.split("/")[0] for source in RESULT_SOURCES} | {"tools"}:  # the whole package
        shutil.copytree(PACKAGE_ROOT / part, copy / part, ignore=shutil.ignore_patterns("__pycache__"))
    with (copy / "agents" / "laws.py").open("a") as laws:
        laws.write("# one line more\n")
    output = tmp_path / "s.json"
    with worker(bare_scheduler, code=copy.parent):
        assert main([*STUDY, "--cluster", bare_scheduler, "--json", str(output)]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"ringtrack: error: --cluster {bare_scheduler}: ringtrack's source on {socket.gethostname()} is not the one "
        "the study began with (its results would differ): give every worker the study's ringtrack, unchanged until "
        "the study ends")
    assert not output.exists() and (tmp_path / "s.journal.jsonl").read_bytes().count(b"\n") == 1  # the header


@pytest.mark.parametrize(("there", "problem"), [
    (None, "heartbeat.py is missing on {host}, where the study's tasks read it (at that path): copy it there"),
    (b"\n# edited there\n", "heartbeat.py on {host} is not the file the study began with (its results would differ): "
                            "give every host the same file, unchanged until the study ends"),
    (b"", None),
], ids=["missing", "edited", "same"])
def test_a_strategy_file_a_worker_reads_must_be_the_studys(there: bytes | None, problem: str | None,
                                                          monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A worker (here: this process, moved to a folder of its own) reads the strategy file at the
    path the study names it by: absent there or edited, it runs nothing and the study says so;
    the same file, it runs the task as the study's machine would."""
    here, elsewhere = tmp_path / "here", tmp_path / "elsewhere"
    here.mkdir()
    elsewhere.mkdir()
    strategy = example(here)
    if there is not None:
        (elsewhere / strategy.name).write_bytes(strategy.read_bytes() + there)
    monkeypatch.chdir(here)
    scenario = random_start_scenarios("paper-stationary", 4, [strategy.name])["heartbeat"]
    task = StationaryTask("heartbeat trials 0-1", 0, [0, 1], "heartbeat", [scenario, scenario], [0, 1])
    began = origin(Study("stationary", {"strategies": [strategy.name]}, [task], stationary_task, StationaryPart))
    local = execute(stationary_task, task)
    monkeypatch.chdir(elsewhere)
    outcome = execute_checked(stationary_task, task, began)
    assert began.files == (strategy.name,) and outcome[0] == socket.gethostname()
    if problem is None:
        assert outcome[1:] == (began.provenance, local) and checked(outcome, began, "here") == local
    else:
        assert outcome[2] is None
        with pytest.raises(UsageError) as raised:
            checked(outcome, began, "--cluster tcp://host:8786")
        assert str(raised.value) == "--cluster tcp://host:8786: " + problem.format(host=outcome[0])


def test_a_studys_files_are_also_the_strategy_files_its_scenarios_name(monkeypatch: pytest.MonkeyPatch,
                                                                      tmp_path: Path) -> None:
    """A scenario file's ``[strategy] name = "my.py"`` is read by every task that runs the scenario,
    though no flag of the study names it."""
    monkeypatch.chdir(tmp_path)
    strategy = example(tmp_path)
    scenario = random_start_scenarios("paper-stationary", 4, [strategy.name])["heartbeat"]
    task = StationaryTask("heartbeat trials 0-1", 0, [0, 1], "heartbeat", [scenario, scenario], [0, 1])
    assert study_files(Study("stationary", {}, [task], stationary_task, StationaryPart)) == (strategy.name,)
    assert study_files(Study("stationary", {"strategies": ["self"]}, [], stationary_task, StationaryPart)) == ()


@dataclass(frozen=True)
class EditingTask(Task):
    """A task of a study whose strategy file (``strategy``, a path) its first task edits."""

    strategy: str


def edit_then_answer(task: EditingTask) -> Seeds:
    """The first task appends a line to the strategy file; every other waits until it has (so that
    it finishes after the edit, whichever worker ran the first), then each returns its seeds."""
    strategy = Path(task.strategy)
    if task.first == 0:
        with strategy.open("a") as file:
            file.write("# edited mid-study\n")
    deadline = time.monotonic() + 60
    while not strategy.read_text().endswith("# edited mid-study\n") and time.monotonic() < deadline:
        time.sleep(0.01)
    return Seeds(task.seeds)


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.processes)])
def test_a_strategy_file_edited_mid_study_stops_it(workers: int, tmp_path: Path) -> None:
    """A file the tasks read is edited while the study runs (a researcher trying a change): the
    tasks that would run with the edited file run nothing, in this process or in a pool's workers,
    and the study stops in one line rather than mix two versions of the strategy in its results."""
    strategy = example(tmp_path)
    tasks = [EditingTask(f"task {index}", index, [index], str(strategy)) for index in range(6)]
    study = Study("editing", {"strategies": [str(strategy)]}, tasks, edit_then_answer, Seeds)
    with pytest.raises(UsageError) as raised:
        run_study(study, Execution(workers=workers))
    assert str(raised.value) == (
        f"experiment editing: {strategy} on {socket.gethostname()} is not the file the study began with (its results "
        "would differ): give every host the same file, unchanged until the study ends")


@pytest.mark.processes
def test_a_study_on_a_scheduler_without_workers_says_so_and_waits_for_one(tmp_path: Path) -> None:
    output, scheduler_file = tmp_path / "s.json", tmp_path / "scheduler.json"
    with dask_process("scheduler", "--port", "0", "--scheduler-file", str(scheduler_file)) as scheduler:
        address = scheduler_address(scheduler_file, scheduler)
        study = subprocess.Popen([*RINGTRACK, *STUDY, "--cluster", address, "--json", str(output)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            assert study.stderr is not None
            ready, _, _ = select.select([study.stderr], [], [], 120)
            assert ready and study.stderr.readline() == (
                f"experiment stationary: the Dask scheduler at {address} has no worker yet; the tasks wait for one "
                f"('dask worker {address}' on a host with ringtrack)\n")
            assert study.poll() is None  # waiting, not failed
            with worker(address):
                _, errors = study.communicate(timeout=120)
        finally:
            study.kill()
            study.wait()
    assert study.returncode == 0 and "Traceback" not in errors
    assert without_wall(output) == run(STUDY, tmp_path, "local", "--workers", "1")[0]


def test_resuming_a_finished_study_on_a_cluster_connects_to_none(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Nothing left to run: the study is written from its journal, and no scheduler is asked (none
    answers at the address given)."""
    small = [*STUDIES["stationary"], "--quiet"]  # 4 tasks
    whole = run(small, tmp_path, "s", "--workers", "1")
    assert run(small, tmp_path, "s", "--resume", "--cluster", "tcp://127.0.0.1:1") == whole
    assert "4 of 4 tasks done, 0 to run" in capsys.readouterr().err
