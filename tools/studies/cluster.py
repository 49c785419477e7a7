"""Tasks on a Dask distributed cluster (``--cluster``, the optional extra ``ringtrack[cluster]``):
each worker runs a task only where it computes with what the study's machine does, and what a
cluster meets (no worker yet, workers that keep dying, a scheduler that goes away) is said in one
line."""

from __future__ import annotations

import contextlib
import importlib
import logging
import socket
from collections.abc import Callable, Generator, Iterator
from concurrent.futures import CancelledError
from types import ModuleType
from typing import NamedTuple

import msgspec

from ringtrack.tools.output.console import UsageError, err
from ringtrack.tools.studies.journal import code_digest, file_digest, named_files
from ringtrack.tools.studies.study import WORKER_DEATH, Study, StudyStopped, TaskT, execute

CLUSTER_EXTRA = "pip install 'ringtrack[cluster]'"


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
    read = worker_files(study)
    expected = provenance(read)
    try:
        client = distributed.Client(address, timeout="20s")
    except (OSError, TimeoutError) as error:
        raise UsageError(f"--cluster {address}: no Dask scheduler answers there ({error}); start one with "
                         "'dask scheduler' and give its tcp://HOST:PORT") from None
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
                raise StudyStopped(f"experiment {study.experiment}: the workers that ran task "
                                   f"'{study.tasks[index_of[future.key]].key}' kept dying ({WORKER_DEATH})") from None
            except (distributed.comm.CommClosedError, CancelledError):
                # the client lost its scheduler: it cancels every future, and a result it was fetching fails
                lost = True
                raise StudyStopped(f"--cluster {address}: the Dask scheduler went away mid-study (lost the "
                                   "connection)") from None
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
    return tuple(sorted({name for name in named_files(study.parameters) if name.endswith(".py")}))


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
