"""Studies as tasks: a study is an ordered list of tasks (a cell or run of the study times a fixed
chunk of its seeds), run in this process, in a pool of local processes (``--workers``) or on a Dask
cluster (``--cluster``), journalled as they finish so that ``--resume`` continues an interrupted
study.

A task's result leaves the process that ran it as JSON (msgspec), and the study is assembled from
the decoded results in the tasks' order, whoever ran them and in whatever order they finished: the
same bytes whether a result came from this process, a pool, a cluster or the journal. Nor do
results depend on the chunks (``batch`` trials each): the engine computes each trial elementwise
along its batch and the studies add trials up exactly (:class:`tools.studies.experiment.StepTotals`),
so ``batch`` only trades engine efficiency (bigger) against parallelism and the work a kill loses
(smaller).

The journal (``PATH.journal.jsonl`` beside the study's ``--json`` or ``--csv`` output) is JSON
lines: a header (:class:`JournalHeader`: the experiment, every parameter that changes results, the
chunk size, a digest of the code and files that compute them), then one :class:`JournalTask` per
finished task, each flushed and fsync'd, so a killed study loses only its tasks in flight; a last
line cut by the kill is left out. ``--resume`` continues only a journal of the same study computed
by the same code from the same files.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import importlib
import logging
import multiprocessing
import os
import socket
from collections.abc import Callable, Generator, Iterator, Mapping
from concurrent.futures import CancelledError, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, BinaryIO, Generic, NamedTuple, TypeVar

import msgspec

from ringtrack.tools.output.console import UsageError, err
from ringtrack.tools.output.files import OutputError
from ringtrack.tools.output.progress import TrialProgress
from ringtrack.tools.team.supervisor import terminate_as_exception

BATCH = 50  # trials per task unless --batch says otherwise (speed only: see the module docstring)
PACKAGE_ROOT = Path(__file__).resolve().parents[2]  # ringtrack's own folder
RESULT_SOURCES = ("agents", "bus", "world", "tools/studies", "scenarios")  # what computes a study's results
POOL_RESTARTS = 3  # new pools a study may start for the tasks of workers that died (as Dask retries them)
KEPT_TASKS = "the tasks finished are in the journal of --json or --csv, which --resume continues"  # a stop's hint
CLUSTER_EXTRA = "pip install 'ringtrack[cluster]'"


class StudyStopped(ValueError):
    """A study stopped by what it ran on rather than by its input (the Dask scheduler went away):
    the message is one line saying what and how to continue; the command exits with ``exit_code``."""

    exit_code = 1


def available_cores() -> int:
    """The cores this process may run on (the default of ``--workers``)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@dataclass(frozen=True)
class Task:
    """One task of a study: ``key`` names it (unique in the study, e.g. ``N=6 self seeds 0-24``),
    ``first`` is the study's index of its first trial, ``seeds`` the seeds of its trials. A study
    adds what its work function needs (scenarios, settings)."""

    key: str
    first: int
    seeds: list[int]

    def cost(self) -> float:
        """How long the task runs beside the study's others, a guess (here: its trials); pools and
        clusters start the costliest first, so that no long task is left running alone at the end."""
        return len(self.seeds)


TaskT = TypeVar("TaskT", bound=Task)
ResultT = TypeVar("ResultT", bound=msgspec.Struct)


@dataclass(frozen=True)
class Study(Generic[TaskT, ResultT]):
    """What the runner runs: the ``experiment``'s name, the ``parameters`` that change its results
    (plain values; the journal's header), its ``tasks`` in the study's order, the module-level
    function ``work`` that runs one task in any process, and the type of its result."""

    experiment: str
    parameters: Mapping[str, object]
    tasks: list[TaskT]
    work: Callable[[TaskT], ResultT]
    result: type[ResultT]


@dataclass(frozen=True)
class Execution:
    """How a study runs: ``workers`` local processes (1: this process), or the Dask scheduler at
    ``cluster`` (``tcp://host:8786``); ``batch`` trials per task; the ``journal`` file (None: none),
    continued with ``resume``; ``quiet``: no progress."""

    workers: int = 1
    cluster: str | None = None
    batch: int = BATCH
    journal: Path | None = None
    resume: bool = False
    quiet: bool = True


IN_PROCESS = Execution()  # a study run from code: in this process, chunks of BATCH, no journal, no progress


def chunks(seeds: list[int], size: int) -> list[tuple[int, list[int]]]:
    """``(first trial index, seeds)`` of the consecutive chunks of ``size`` seeds (the last may be short)."""
    return [(start, seeds[start:start + size]) for start in range(0, len(seeds), size)]


def seed_range(seeds: list[int]) -> str:
    """``seeds 0-24``: a chunk's seeds as a task's key names them."""
    return f"seeds {seeds[0]}-{seeds[-1]}"


def journal_path(*outputs: Path | None) -> Path | None:
    """Where a study's journal lives: beside the first output given (``out.json``:
    ``out.journal.jsonl``); None when the study writes no file."""
    for output in outputs:
        if output is not None:
            return output.with_suffix(".journal.jsonl")
    return None


# ---------------------------------------------------------------------------------------- journal
class JournalHeader(msgspec.Struct, frozen=True, tag="study"):
    """The journal's first line: the experiment, the parameters that change its results, the
    trials per task, and the digest of the code and files that compute them (:func:`inputs_digest`;
    empty in journals written before it was kept)."""

    experiment: str
    batch: int
    parameters: dict[str, Any]
    inputs: str = ""


class JournalTask(msgspec.Struct, frozen=True, tag="task"):
    """A finished task: its index in the study's order, its key and its result (JSON)."""

    index: int
    key: str
    result: msgspec.Raw


JOURNAL_LINE = msgspec.json.Decoder(JournalHeader | JournalTask)


def header_of(study: Study, batch: int) -> JournalHeader:
    """The journal header of ``study`` cut in chunks of ``batch`` trials, its parameters as JSON
    gives them back (tuples as lists), so that a header read from a journal compares equal."""
    parameters = msgspec.json.decode(msgspec.json.encode(dict(study.parameters)))
    return JournalHeader(experiment=study.experiment, batch=batch, parameters=parameters,
                         inputs=inputs_digest(parameters))


def inputs_digest(parameters: Mapping[str, object]) -> str:
    """What a study's results depend on besides its parameters' values, as a SHA-256 (hex): the
    source of the code that computes them (:func:`code_digest`) and the contents of every file the
    ``parameters`` name (a scenario's TOML, a strategy's Python file)."""
    digest = hashlib.sha256(code_digest().encode())
    for name in sorted(set(_named_files(parameters))):
        digest.update(f"{name}\0{file_digest(name)}\0".encode())
    return digest.hexdigest()


@functools.cache
def code_digest() -> str:
    """SHA-256 (hex) of ringtrack's source that computes a study's results (:data:`RESULT_SOURCES`)
    as installed where this runs: equal on two machines exactly when they compute the same results."""
    digest = hashlib.sha256()
    for folder in RESULT_SOURCES:
        for path in sorted((PACKAGE_ROOT / folder).rglob("*")):
            if path.suffix in (".py", ".toml") and path.is_file():
                digest.update(f"{path.relative_to(PACKAGE_ROOT).as_posix()}\0".encode())
                digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def file_digest(name: str) -> str | None:
    """SHA-256 (hex) of the file at path ``name`` where this runs; None where there is none."""
    path = Path(name)
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def _named_files(value: object) -> Iterator[str]:
    """The strings in ``value`` (nested lists and mappings) that name existing files."""
    if isinstance(value, str):
        if value and Path(value).is_file():
            yield value
    elif isinstance(value, Mapping):
        for item in value.values():
            yield from _named_files(item)
    elif isinstance(value, list | tuple):
        for item in value:
            yield from _named_files(item)


def header_difference(found: JournalHeader, wanted: JournalHeader) -> str | None:
    """The first setting in which two headers differ, as ``trials 30 there, 40 here``; None: equal."""
    there = {"experiment": found.experiment, "batch": found.batch, **found.parameters}
    here = {"experiment": wanted.experiment, "batch": wanted.batch, **wanted.parameters}
    for name in dict.fromkeys([*here, *there]):
        if there.get(name) != here.get(name):
            return f"{name} {there.get(name)} there, {here.get(name)} here"
    return None


def whole_lines(path: Path) -> bytes:
    """The journal's bytes up to its last newline (a line cut by a kill mid-write is left out)."""
    data = path.read_bytes()
    return data[: data.rfind(b"\n") + 1]


def read_journal(path: Path, study: Study, header: JournalHeader) -> dict[int, bytes]:
    """The results (JSON) of the tasks a journal records, by index; a :class:`UsageError` naming
    ``--resume`` when there is no journal, it is of another study or a line is not a record."""
    if not path.is_file():
        raise UsageError(f"--resume: no journal at {path}; run without --resume to start the study")
    lines = whole_lines(path).splitlines()
    done: dict[int, bytes] = {}
    for number, line in enumerate(lines, 1):
        try:
            record = JOURNAL_LINE.decode(line)
        except msgspec.DecodeError:
            raise UsageError(f"--resume: {path} line {number} is not a journal record; run without --resume "
                             "to start over") from None
        if number == 1:
            if not isinstance(record, JournalHeader):
                raise UsageError(f"--resume: {path} does not start with a study header; run without --resume")
            difference = header_difference(record, header)
            if difference is not None:
                raise UsageError(f"--resume: {path} is the journal of another study ({difference}); "
                                 "give the same flags or run without --resume to start over")
            if record.inputs != header.inputs:
                raise UsageError(f"--resume: {path} was written by other code or from other files (ringtrack's "
                                 "source or a file the study reads has changed since); finish it with what began "
                                 "it, or run without --resume to start over")
        elif not (isinstance(record, JournalTask) and record.index < len(study.tasks)
                  and study.tasks[record.index].key == record.key):
            raise UsageError(f"--resume: {path} line {number} is no task of this study; run without --resume")
        else:
            done[record.index] = bytes(record.result)
    if not lines:
        raise UsageError(f"--resume: {path} is empty; run without --resume to start the study")
    return done


@contextlib.contextmanager
def journal_file(path: Path | None, header: JournalHeader, resume: bool) -> Iterator[BinaryIO | None]:
    """The journal opened for appending (:func:`locked_journal`): continued (cut to its whole lines)
    with ``resume``, else started afresh with its header (saying so on stderr when it replaces one).
    None: no journal."""
    if path is None:
        yield None
        return
    replacing = not resume and path.exists()
    path.parent.mkdir(parents=True, exist_ok=True)
    with locked_journal(path) as file:
        if resume:
            file.truncate(len(whole_lines(path)))
        else:
            if replacing:
                err.print(f"experiment {header.experiment}: replacing the journal {path} (--resume continues one)",
                          highlight=False, markup=False)
            if os.fstat(file.fileno()).st_size:
                file.truncate(0)
            append(file, msgspec.json.encode(header))
        yield file


@contextlib.contextmanager
def locked_journal(path: Path) -> Iterator[BinaryIO]:
    """``path`` opened unbuffered for appending (made if absent, not cut) under an exclusive lock held
    until it is closed, so that two studies never write one journal (the same command started
    twice): a :class:`UsageError` when another process holds it (where the file system has locks)."""
    with path.open("a+b", buffering=0) as file:
        try:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UsageError(f"{path}: another study is writing this journal (the same command running "
                             "elsewhere?); wait for it to end, or give another --json or --csv") from None
        except OSError:  # a file system without locks (some network or FUSE ones): the journal goes unguarded
            pass
        yield file


def append(file: BinaryIO, line: bytes) -> None:
    """Write one journal line to the (unbuffered) journal and make it durable (fsync'd) before going
    on; a full disk raises :class:`OutputError` saying that ``--resume`` continues from the lines
    written (a line cut short is left out)."""
    rest = memoryview(line + b"\n")
    try:
        while rest:
            rest = rest[file.write(rest):]
        os.fsync(file.fileno())
    except OSError as error:
        raise OutputError(f"{file.name}: not written ({error.strerror or error}); the study's finished tasks "
                          "are kept there: make room and run it again with --resume") from None


# ---------------------------------------------------------------------------------------- running
def execute(work: Callable[[TaskT], msgspec.Struct], task: TaskT) -> bytes:
    """Run one task (in any process) and return its result as JSON: how every result travels."""
    return msgspec.json.encode(work(task))


def run_study(study: Study[TaskT, ResultT], execution: Execution) -> list[ResultT]:
    """Run the study's tasks not yet journalled (all unless ``execution.resume``), journal each as it
    finishes and return every task's result in the study's order."""
    header = header_of(study, execution.batch)
    label = f"experiment {study.experiment}"
    if execution.resume and execution.journal is None:
        raise UsageError("--resume: give the --json or --csv of the interrupted study (its journal lies beside it)")
    if execution.cluster is not None:
        dask_distributed()  # a missing extra is reported before any journal is touched
    results = read_journal(execution.journal, study, header) if execution.resume and execution.journal else {}
    pending = [index for index in range(len(study.tasks)) if index not in results]
    if execution.resume:
        err.print(f"{label}: resuming {execution.journal}: {len(results)} of {len(study.tasks)} tasks done, "
                  f"{len(pending)} to run", highlight=False, markup=False)
    total = sum(len(task.seeds) for task in study.tasks)
    done = sum(len(study.tasks[index].seeds) for index in results)
    with (terminate_as_exception(),  # a SIGTERM ends the workers and keeps the journal, as Ctrl-C does
          journal_file(execution.journal, header, execution.resume) as journal,
          TrialProgress(label, total, done, execution.quiet) as progress,
          contextlib.closing(finished(study, pending, execution)) as outcomes):
        for index, result in outcomes:
            if journal is not None:
                append(journal, msgspec.json.encode(JournalTask(index, study.tasks[index].key, msgspec.Raw(result))))
            results[index] = result
            progress.advance(len(study.tasks[index].seeds))
    decoder = msgspec.json.Decoder(study.result)
    return [decoder.decode(results[index]) for index in range(len(study.tasks))]


def finished(study: Study, pending: list[int], execution: Execution) -> Generator[tuple[int, bytes], None, None]:
    """``(task index, result)`` of the ``pending`` tasks as they finish, wherever they run."""
    if execution.cluster is not None:
        return on_cluster(study, costliest_first(study, pending), execution.cluster)
    if execution.workers > 1 and len(pending) > 1:
        return in_pool(study, costliest_first(study, pending), execution.workers)
    return ((index, execute(study.work, study.tasks[index])) for index in pending)


def costliest_first(study: Study, pending: list[int]) -> list[int]:
    """The ``pending`` tasks by :meth:`Task.cost`, highest first (the study's order among equals):
    the order a pool or a cluster is given them in (results are assembled by index, whatever the order)."""
    return sorted(pending, key=lambda index: -study.tasks[index].cost())


def in_pool(study: Study, pending: list[int], workers: int) -> Generator[tuple[int, bytes], None, None]:
    """Run the tasks in up to ``workers`` local processes (:func:`worker_pool`); the pool is shut
    down, its queued tasks cancelled, however the loop ends (an error, Ctrl-C). A worker that dies
    (killed, out of memory) breaks the pool and every task it had not finished: those run again in a
    new pool (a task's result does not depend on where or how often it ran), saying so on stderr,
    at most :data:`POOL_RESTARTS` times in a study."""
    restarts = 0
    while pending:
        lost = []
        with worker_pool(study.work.__module__, min(workers, len(pending))) as pool:
            futures = {pool.submit(execute, study.work, study.tasks[index]): index for index in pending}
            for future in as_completed(futures):
                try:
                    result = future.result()
                except BrokenProcessPool:
                    lost.append(futures[future])
                    continue
                yield futures[future], result
        if lost:
            restarts += 1
            if restarts > POOL_RESTARTS:
                raise UsageError(f"experiment {study.experiment}: a worker process died {restarts} times (killed, or "
                                 f"out of memory: try fewer --workers or a smaller --batch); {KEPT_TASKS}")
            err.print(f"experiment {study.experiment}: a worker process died (killed, or out of memory); running "
                      f"its pool's {len(lost)} unfinished tasks in a new pool ({restarts} of {POOL_RESTARTS})",
                      highlight=False, markup=False)
        pending = [index for index in pending if index in lost]  # in the order given


@contextlib.contextmanager
def worker_pool(module: str, workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` local processes started by a fork server (this process may run a
    progress thread, which a fork would copy mid-flight) that has imported ``module`` (the work's:
    numpy, the engine) once, so that each worker forks from it ready (a preload counts when this
    process starts its fork server, at its first pool); shut down on leaving, queued tasks cancelled."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([module])
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
    try:
        yield pool
    except BaseException:  # Ctrl-C, SIGTERM, an error, or the caller leaving: the tasks in flight are lost
        end_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def end_workers(pool: ProcessPoolExecutor) -> None:
    """Stop the pool's worker processes now (SIGTERM), whatever task they run, so that leaving a pool
    early never waits for its running tasks nor leaves them running (``terminate_workers`` from
    Python 3.14; its table of processes before)."""
    for process in list((pool._processes or {}).values()):
        process.terminate()


def dask_distributed() -> ModuleType:
    """``dask.distributed``, or a :class:`UsageError` naming the extra that installs it."""
    try:
        return importlib.import_module("dask.distributed")
    except ImportError:
        raise UsageError(f"--cluster needs Dask: {CLUSTER_EXTRA}") from None


def on_cluster(study: Study, pending: list[int], address: str) -> Generator[tuple[int, bytes], None, None]:
    """Run the tasks on the Dask scheduler at ``address`` (its workers import ringtrack); the client
    is closed however the loop ends. A scheduler with no worker yet is said on stderr (the tasks
    wait). A worker runs a task only where it computes with what this machine does
    (:func:`execute_checked`), else the study stops in one line naming the worker and what differs.
    The scheduler runs again the tasks of a worker that died; a task whose workers kept dying
    (Dask's ``allowed-failures``) ends the study in one line, and so does a scheduler that goes away."""
    distributed = dask_distributed()
    try:
        client = distributed.Client(address, timeout="20s")
    except (OSError, TimeoutError) as error:
        raise UsageError(f"--cluster {address}: no Dask scheduler answers there ({error}); start one with "
                         "'dask scheduler' and give its tcp://HOST:PORT") from None
    read = worker_files(study)
    expected = provenance(read)
    lost = False
    try:
        if not client.scheduler_info()["workers"]:
            err.print(f"experiment {study.experiment}: the Dask scheduler at {address} has no worker yet; the tasks "
                      f"wait for one ('dask worker {address}' on a host with ringtrack)", highlight=False, markup=False)
        futures = [client.submit(execute_checked, study.work, study.tasks[index], read, expected, pure=False)
                   for index in pending]
        index_of = {future.key: index for future, index in zip(futures, pending, strict=True)}
        for future in distributed.as_completed(futures):
            try:
                host, found, result = future.result()
            except distributed.KilledWorker:
                raise UsageError(f"experiment {study.experiment}: the workers that ran task "
                                 f"'{study.tasks[index_of[future.key]].key}' kept dying (killed, or out of memory); "
                                 f"{KEPT_TASKS}") from None
            except (distributed.comm.CommClosedError, CancelledError):
                # the client lost its scheduler: it cancels every future, and a result it was fetching fails
                lost = True
                raise StudyStopped(f"--cluster {address}: the Dask scheduler went away mid-study (lost the "
                                   f"connection); {KEPT_TASKS}, here or on a scheduler started again") from None
            if result is None:
                raise UsageError(f"--cluster {address}: {difference(host, found, expected, read)}")
            yield index_of[future.key], result
    finally:
        with logs_silenced() if lost else contextlib.nullcontext():
            client.close()  # after a loss, without the traceback of the reconnection it cancels


class Provenance(NamedTuple):
    """What a machine computes a study's results with: ringtrack's source there (:func:`code_digest`)
    and the :func:`file_digest` there of each file the study's workers read."""

    code: str
    files: tuple[str | None, ...]


def provenance(files: tuple[str, ...]) -> Provenance:
    """The :class:`Provenance` of this machine for a study whose workers read ``files`` (paths)."""
    return Provenance(code_digest(), tuple(file_digest(name) for name in files))


def worker_files(study: Study) -> tuple[str, ...]:
    """The files a worker reads itself at the path the study names them by: its strategy files
    (``.py``; a scenario's TOML is read here, and its content travels in the task)."""
    return tuple(sorted({name for name in _named_files(study.parameters) if name.endswith(".py")}))


def execute_checked(work: Callable[[TaskT], msgspec.Struct], task: TaskT, files: tuple[str, ...],
                    expected: Provenance) -> tuple[str, Provenance, bytes | None]:
    """Run ``task`` on a cluster worker (:func:`execute`) if the worker computes with what the
    study's machine does (``expected``, for the ``files`` workers read): the worker's host name, its
    :class:`Provenance`, and the result (None: not run, as it could differ from a local run's)."""
    found = provenance(files)
    return socket.gethostname(), found, execute(work, task) if found == expected else None


def difference(host: str, found: Provenance, expected: Provenance, files: tuple[str, ...]) -> str:
    """What differs on the worker on ``host`` from this machine, and the fix, in one line."""
    if found.code != expected.code:
        return (f"the worker on {host} runs other ringtrack code than this machine (its results would differ from "
                "a local run's); install the same ringtrack on every worker")
    name, there = next((name, there) for name, there, here in zip(files, found.files, expected.files, strict=True)
                       if there != here)
    if there is None:
        return f"the worker on {host} has no {name} (a worker reads it at that path); copy it to every worker's host"
    return f"{name} on the worker on {host} differs from this machine's; copy this one to every worker's host"


@contextlib.contextmanager
def logs_silenced() -> Iterator[None]:
    """Drop every log record while in the block (:func:`logging.disable`)."""
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)
