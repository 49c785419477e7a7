"""What a study's results are computed with, and the check that every task is computed with what the
study began with: the same ringtrack source (:func:`code_digest`) and the same files its tasks read
where they run (its strategy files). A task run elsewhere (a pool's worker, a cluster's) or later
(a file edited mid-study) with anything else runs nothing, and the study stops in one line saying
what differs: its results never mix two versions.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import socket
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import NamedTuple

import msgspec

from ringtrack.tools.output.console import UsageError
from ringtrack.tools.studies.study import Study, Task, TaskT, execute
from ringtrack.world.scenario import Scenario

PACKAGE_ROOT = Path(__file__).resolve().parents[2]  # ringtrack's own folder
RESULT_SOURCES = ("agents", "bus", "world", "tools/studies", "scenarios")  # what computes a study's results


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


def named_files(value: object) -> Iterator[str]:
    """The strings in ``value`` (nested lists and mappings) that name existing files."""
    if isinstance(value, str):
        if value and Path(value).is_file():
            yield value
    elif isinstance(value, Mapping):
        for item in value.values():
            yield from named_files(item)
    elif isinstance(value, list | tuple):
        for item in value:
            yield from named_files(item)


def scenario_files(task: Task) -> Iterator[str]:
    """The strategy files (paths of ``.py`` files) that the scenarios a ``task`` runs name (its
    fields holding a :class:`Scenario` or a list of them): a task reads them where it runs."""
    for field in dataclasses.fields(task):
        value = getattr(task, field.name)
        for scenario in value if isinstance(value, list) else [value]:
            if isinstance(scenario, Scenario) and scenario.strategy.name.endswith(".py"):
                yield scenario.strategy.name


def study_files(study: Study) -> tuple[str, ...]:
    """The files ``study``'s tasks read where they run, as the study names them, sorted: the strategy
    files its parameters name (``--strategies my.py``) and those its tasks' scenarios name (a
    scenario file's ``[strategy] name = "my.py"``). A scenario's TOML is read where the study
    starts, and its content travels in the task."""
    names = {name for name in named_files(study.parameters) if name.endswith(".py")}
    return tuple(sorted(names.union(*(scenario_files(task) for task in study.tasks))))


class Provenance(NamedTuple):
    """What a machine computes a study's results with: ringtrack's source there (:func:`code_digest`)
    and the :func:`file_digest` there of each file the study's tasks read where they run."""

    code: str
    files: tuple[str | None, ...]


class Origin(NamedTuple):
    """What a study began with: the ``files`` its tasks read where they run (paths, as the study
    names them) and the study's machine's :class:`Provenance` for them when it began."""

    files: tuple[str, ...]
    provenance: Provenance


def provenance(files: tuple[str, ...]) -> Provenance:
    """The :class:`Provenance` of this machine, now, for tasks that read ``files`` (paths)."""
    return Provenance(code_digest(), tuple(file_digest(name) for name in files))


def origin(study: Study) -> Origin:
    """What ``study`` begins with here: its :func:`study_files` and their digests now."""
    files = study_files(study)
    return Origin(files, provenance(files))


def execute_checked(work: Callable[[TaskT], msgspec.Struct], task: TaskT,
                    began: Origin) -> tuple[str, Provenance, bytes | None]:
    """Run ``task`` (:func:`execute`) where this is called if it computes with what the study
    ``began`` with: the host name, the :class:`Provenance` here, and the result (None: not run, as
    it would differ from the study's other tasks)."""
    found = provenance(began.files)
    return socket.gethostname(), found, execute(work, task) if found == began.provenance else None


def checked(outcome: tuple[str, Provenance, bytes | None], began: Origin, where: str) -> bytes:
    """The result of an :func:`execute_checked` ``outcome``; a :class:`UsageError` starting with
    ``where`` (``--cluster ADDRESS``, ``experiment NAME``) that says what differs and the fix when
    the task did not run."""
    host, found, result = outcome
    if result is not None:
        return result
    if found.code != began.provenance.code:
        raise UsageError(f"{where}: ringtrack's source on {host} is not the one the study began with (its results "
                         "would differ): give every worker the study's ringtrack, unchanged until the study ends")
    name, there = next((name, there) for name, there, here in zip(began.files, found.files, began.provenance.files,
                                                                  strict=True) if there != here)
    if there is None:
        raise UsageError(f"{where}: {name} is missing on {host}, where the study's tasks read it (at that path): "
                         "copy it there")
    raise UsageError(f"{where}: {name} on {host} is not the file the study began with (its results would differ): "
                     "give every host the same file, unchanged until the study ends")
