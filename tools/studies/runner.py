"""Running a study (:mod:`tools.studies.study`): its tasks not yet journalled run in this process, in
a pool of local processes (``--workers``, :mod:`tools.studies.pool`) or on a Dask cluster
(``--cluster``, :mod:`tools.studies.cluster`), and each is journalled as it finishes
(:mod:`tools.studies.journal`) so that ``--resume`` continues an interrupted study.

The study is assembled from the decoded results in the tasks' order, whoever ran them and in
whatever order they finished: the same bytes whether a result came from this process, a pool, a
cluster or the journal.
"""

from __future__ import annotations

import contextlib
from collections.abc import Generator

import msgspec

from ringtrack.tools.output.console import UsageError, err
from ringtrack.tools.output.progress import TrialProgress
from ringtrack.tools.studies.cluster import dask_distributed, on_cluster
from ringtrack.tools.studies.journal import JournalTask, append, header_of, journal_file, kept_tasks, read_journal
from ringtrack.tools.studies.pool import in_pool
from ringtrack.tools.studies.provenance import Origin, checked, execute_checked, origin
from ringtrack.tools.studies.study import Execution, ResultT, Study, StudyStopped, TaskT
from ringtrack.tools.team.supervisor import terminate_as_exception


def run_study(study: Study[TaskT, ResultT], execution: Execution) -> list[ResultT]:
    """Run the study's tasks not yet journalled (all unless ``execution.resume``), journal each as it
    finishes and return every task's result in the study's order."""
    began = origin(study)
    header = header_of(study, began.files)
    if execution.resume and execution.journal is None:
        raise UsageError("--resume: give the --json or --csv of the interrupted study (its journal lies beside it)")
    if execution.cluster is not None:
        dask_distributed()  # a missing extra is reported before any journal is touched
    results = read_journal(execution.journal, study, header) if execution.resume and execution.journal else {}
    pending = [index for index in range(len(study.tasks)) if index not in results]
    total = sum(len(task.seeds) for task in study.tasks)
    done = sum(len(study.tasks[index].seeds) for index in results)
    try:
        with (terminate_as_exception(),  # a SIGTERM ends the workers and keeps the journal, as Ctrl-C does
              journal_file(execution.journal, header, execution.resume) as journal,
              TrialProgress(study.label, total, done, execution.quiet) as progress,
              contextlib.closing(finished(study, pending, execution, began)) as outcomes):
            if execution.resume:  # said once the journal is this study's to continue (locked)
                err.print(f"{study.label}: resuming {execution.journal}: {len(results)} of {len(study.tasks)} tasks "
                          f"done, {len(pending)} to run", highlight=False, markup=False)
            for index, result in outcomes:
                if journal is not None:
                    append(journal, msgspec.json.encode(JournalTask(index, study.tasks[index].key,
                                                                    msgspec.Raw(result))))
                results[index] = result
                progress.advance(len(study.tasks[index].seeds))
    except StudyStopped as stopped:
        raise StudyStopped(f"{stopped}; {kept_tasks(execution.journal)}") from None
    decoder = msgspec.json.Decoder(study.result)
    return [decoder.decode(results[index]) for index in range(len(study.tasks))]


def finished(study: Study, pending: list[int], execution: Execution,
             began: Origin) -> Generator[tuple[int, bytes], None, None]:
    """``(task index, result)`` of the ``pending`` tasks as they finish, wherever they run, each
    computed with what the study ``began`` with (:mod:`tools.studies.provenance`; none pending:
    nothing is started, not even a cluster's client)."""
    if execution.cluster is not None and pending:
        return on_cluster(study, costliest_first(study, pending), execution.cluster, began)
    if execution.workers > 1 and len(pending) > 1:
        return in_pool(study, costliest_first(study, pending), execution.workers, began)
    return ((index, checked(execute_checked(study.work, study.tasks[index], began), began, study.label))
            for index in pending)


def costliest_first(study: Study, pending: list[int]) -> list[int]:
    """The ``pending`` tasks by :meth:`Task.cost`, highest first (the study's order among equals):
    the order a pool or a cluster is given them in (results are assembled by index, whatever the order)."""
    return sorted(pending, key=lambda index: -study.tasks[index].cost())
