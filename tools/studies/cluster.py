"""Tasks on a Dask distributed cluster (``--cluster``, the optional extra ``ringtrack[cluster]``):
each worker runs a task only where it computes with what the study began with
(:mod:`tools.studies.provenance`), and what a cluster meets (no worker yet, workers that keep
dying, a scheduler that goes away) is said in one line."""

from __future__ import annotations

import contextlib
import importlib
import logging
from collections.abc import Generator, Iterator
from concurrent.futures import CancelledError
from types import ModuleType

from ringtrack.tools.output.console import UsageError, err
from ringtrack.tools.studies.provenance import Origin, checked, execute_checked
from ringtrack.tools.studies.study import WORKER_DEATH, Study, StudyStopped

CLUSTER_EXTRA = "pip install 'ringtrack[cluster]'"


def dask_distributed() -> ModuleType:
    """``dask.distributed``, or a :class:`UsageError` naming the extra that installs it."""
    try:
        return importlib.import_module("dask.distributed")
    except ImportError:
        raise UsageError(f"--cluster needs Dask: {CLUSTER_EXTRA}") from None


def on_cluster(study: Study, pending: list[int], address: str,
               began: Origin) -> Generator[tuple[int, bytes], None, None]:
    """Run the tasks on the Dask scheduler at ``address`` (its workers import ringtrack); the client
    is closed however the loop ends. A scheduler with no worker yet is said on stderr (the tasks
    wait). A worker runs a task only where it computes with what the study ``began`` with
    (:func:`execute_checked`), else the study stops in one line naming the worker and what differs.
    The scheduler runs again the tasks of a worker that died; a task whose workers kept dying
    (Dask's ``allowed-failures``) ends the study in one line, and so does a scheduler that goes away."""
    distributed = dask_distributed()
    try:
        client = distributed.Client(address, timeout="20s")
    except (OSError, TimeoutError) as error:
        raise UsageError(f"--cluster {address}: no Dask scheduler answers there ({error}); start one with "
                         "'dask scheduler' and give its tcp://HOST:PORT") from None
    lost = False
    try:
        if not client.scheduler_info()["workers"]:
            err.print(f"{study.label}: the Dask scheduler at {address} has no worker yet; the tasks "
                      f"wait for one ('dask worker {address}' on a host with ringtrack)", highlight=False, markup=False)
        futures = [client.submit(execute_checked, study.work, study.tasks[index], began, pure=False)
                   for index in pending]
        index_of = {future.key: index for future, index in zip(futures, pending, strict=True)}
        for future in distributed.as_completed(futures):
            try:
                outcome = future.result()
            except distributed.KilledWorker:
                raise StudyStopped(f"{study.label}: the workers that ran task "
                                   f"'{study.tasks[index_of[future.key]].key}' kept dying ({WORKER_DEATH})") from None
            except (distributed.comm.CommClosedError, CancelledError):
                # the client lost its scheduler: it cancels every future, and a result it was fetching fails
                lost = True
                raise StudyStopped(f"--cluster {address}: the Dask scheduler went away mid-study (lost the "
                                   "connection)") from None
            yield index_of[future.key], checked(outcome, began, f"--cluster {address}")
    finally:
        with logs_silenced() if lost else contextlib.nullcontext():
            client.close()  # after a loss, without the traceback of the reconnection it cancels


@contextlib.contextmanager
def logs_silenced() -> Iterator[None]:
    """Drop every log record while in the block (:func:`logging.disable`)."""
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)
