"""What a study is: an ordered list of tasks (a cell or run of the study times a fixed chunk of its
seeds), the module-level function that runs one task in any process, and how the study is run
(:class:`Execution`). A task's result leaves the process that ran it as JSON (:func:`execute`).

Results do not depend on the chunks (``batch`` trials each): the engine computes each trial
elementwise along its batch and the studies add trials up exactly
(:class:`tools.studies.experiment.StepTotals`), so ``batch`` only trades engine efficiency (bigger)
against parallelism and the work a kill loses (smaller).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

import msgspec

BATCH = 50  # trials per task unless --batch says otherwise (speed only: see this module's docstring)
WORKER_DEATH = "killed, or out of memory"  # what ends a worker process that was not asked to end


class StudyStopped(ValueError):
    """A study stopped by what it ran on rather than by its input (workers that kept dying, a Dask
    scheduler that went away): the message is one line saying what, to which the runner adds where
    the finished tasks are kept (:func:`tools.studies.journal.kept_tasks`); the command exits with
    ``exit_code``."""

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
ItemT = TypeVar("ItemT")
ResultT = TypeVar("ResultT", bound=msgspec.Struct)


@dataclass(frozen=True)
class Study(Generic[TaskT, ResultT]):
    """What the runner runs: the ``experiment``'s name, the ``parameters`` that change its results
    (plain values; the journal's header), its ``tasks`` in the study's order, the module-level
    function ``work`` that runs one task in any process, the type of its result, and the ``batch``
    of trials per task its tasks were cut into (the journal's header keeps it)."""

    experiment: str
    parameters: Mapping[str, object]
    tasks: list[TaskT]
    work: Callable[[TaskT], ResultT]
    result: type[ResultT]
    batch: int = BATCH

    @property
    def label(self) -> str:
        """How the study's lines on stderr and its errors name it: ``experiment NAME``."""
        return f"experiment {self.experiment}"


@dataclass(frozen=True)
class Execution:
    """How a study runs: ``workers`` local processes (1: this process), or the Dask scheduler at
    ``cluster`` (``tcp://host:8786``); ``batch`` trials per task (None: the study's own,
    :meth:`trials_per_task`); the ``journal`` file (None: none), continued with ``resume``;
    ``quiet``: no progress."""

    workers: int = 1
    cluster: str | None = None
    batch: int | None = None
    journal: Path | None = None
    resume: bool = False
    quiet: bool = True


    def trials_per_task(self, default: int = BATCH) -> int:
        """The trials of a task: ``batch``, else the study's ``default``."""
        return self.batch or default


IN_PROCESS = Execution()  # a study run from code: in this process, its own chunks, no journal, no progress


def chunks(trials: list[ItemT], size: int) -> list[tuple[int, list[ItemT]]]:
    """``(first trial index, trials)`` of the consecutive chunks of ``size`` trials (their seeds, or
    what else names them; the last may be short)."""
    return [(start, trials[start:start + size]) for start in range(0, len(trials), size)]


def seed_range(seeds: list[int]) -> str:
    """``seeds 0-24``: a chunk's seeds as a task's key names them."""
    return f"seeds {seeds[0]}-{seeds[-1]}"


def execute(work: Callable[[TaskT], msgspec.Struct], task: TaskT) -> bytes:
    """Run one task (in any process) and return its result as JSON: how every result travels."""
    return msgspec.json.encode(work(task))
