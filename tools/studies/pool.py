"""Tasks in a pool of local processes (``--workers``), forked ready from a fork server; a worker that
dies costs only the tasks its pool had not finished, which run again in a new pool."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import select
import threading
import time
from collections.abc import Generator, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from ringtrack.tools.output.console import err
from ringtrack.tools.studies.provenance import Origin, checked, execute_checked
from ringtrack.tools.studies.study import WORKER_DEATH, Study, StudyStopped

POOL_RESTARTS = 3  # new pools a study may start for the tasks of workers that died (as Dask retries them)


def in_pool(study: Study, pending: list[int], workers: int,
            began: Origin) -> Generator[tuple[int, bytes], None, None]:
    """Run the tasks in up to ``workers`` local processes (:func:`worker_pool`), each only where it
    computes with what the study ``began`` with (:func:`tools.studies.provenance.checked`). However
    the loop ends early (an error, Ctrl-C, SIGTERM), the pool's workers are ended and its queued
    tasks cancelled. A worker that dies (killed, out of memory) breaks the pool and every task it
    had not finished: those run again in a new pool (a task's result does not depend on where or
    how often it ran), saying so on stderr, at most :data:`POOL_RESTARTS` times in a study."""
    restarts = 0
    while pending:
        lost = []
        with worker_pool(study.work.__module__, min(workers, len(pending))) as pool:
            futures = {pool.submit(execute_checked, study.work, study.tasks[index], began): index for index in pending}
            for future in as_completed(futures):
                try:
                    outcome = future.result()
                except BrokenProcessPool:
                    lost.append(futures[future])
                    continue
                yield futures[future], checked(outcome, began, study.label)
        if lost:
            restarts += 1
            if restarts > POOL_RESTARTS:
                raise StudyStopped(f"{study.label}: a worker process died {restarts} times "
                                   f"({WORKER_DEATH}: try fewer --workers or a smaller --batch)")
            err.print(f"{study.label}: a worker process died ({WORKER_DEATH}); running "
                      f"its pool's {len(lost)} unfinished tasks in a new pool ({restarts} of {POOL_RESTARTS})",
                      highlight=False, markup=False)
        pending = [index for index in pending if index in lost]  # in the order given


@contextlib.contextmanager
def worker_pool(module: str, workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of ``workers`` local processes started by a fork server (this process may run a
    progress thread, which a fork would copy mid-flight) that has imported ``module`` (the work's:
    numpy, the engine) once, so that each worker forks from it ready (a preload counts when this
    process starts its fork server, at its first pool); shut down on leaving, queued tasks cancelled,
    and its workers ended at once (:func:`end_workers`) when the block is left by an exception."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([module])
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=end_with, initargs=(os.getpid(),))
    try:
        yield pool
    except BaseException:  # Ctrl-C, SIGTERM, an error, or the caller leaving: the tasks in flight are lost
        end_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def end_with(study: int) -> None:
    """Make this worker end as soon as the process ``study`` (a pid) does, however it ends: a worker
    forked by the fork server is no child of the study's process, and it waits for tasks on a queue
    whose other end it holds itself, so after a ``kill -9`` of the study nothing else would end it.
    The fork server and multiprocessing's resource tracker end once the last of its workers has."""
    threading.Thread(target=_exit_after, args=(study,), name="end-with-study", daemon=True).start()


def _exit_after(pid: int) -> None:
    """Wait until the process ``pid`` has ended, then end this one at once (its work is nobody's)."""
    try:
        handle = os.pidfd_open(pid)  # Linux 5.3 and later: readable once the process has ended
    except ProcessLookupError:
        pass
    except (AttributeError, OSError):  # no pidfd here: look every second
        with contextlib.suppress(ProcessLookupError, PermissionError):
            while True:
                os.kill(pid, 0)
                time.sleep(1.0)
    else:
        select.select([handle], [], [])
    os._exit(1)


def end_workers(pool: ProcessPoolExecutor) -> None:
    """Stop the pool's worker processes now (SIGTERM), whatever task they run, so that leaving a pool
    early never waits for its running tasks nor leaves them running (``terminate_workers`` from
    Python 3.14; its table of processes before)."""
    for process in list((pool._processes or {}).values()):
        process.terminate()
