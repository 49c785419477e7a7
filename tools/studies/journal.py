"""A study's journal: ``PATH.journal.jsonl`` beside the study's ``--json`` or ``--csv`` output, JSON
lines: a header (:class:`JournalHeader`: the experiment, every parameter that changes results, the
chunk size, a digest of the code and files that compute them), then one :class:`JournalTask` per
finished task, each written whole and fsync'd, so a killed study loses only its tasks in flight; a last
line cut by the kill is left out. ``--resume`` continues only a journal of the same study computed
by the same code from the same files. A study holds its journal under an exclusive lock.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import msgspec

from ringtrack.tools.output.console import UsageError, err
from ringtrack.tools.output.files import OutputError
from ringtrack.tools.studies.provenance import code_digest, file_digest, named_files
from ringtrack.tools.studies.study import Study


def kept_tasks(journal: Path | None) -> str:
    """What a study stopped half-way says of its finished tasks: where ``journal`` keeps them for
    ``--resume``, or that a study without one (no ``--json``, no ``--csv``) keeps none."""
    if journal is None:
        return "its finished tasks are not kept (give --json or --csv: their journal keeps them for --resume)"
    return f"its finished tasks are kept in {journal}: run the same command with --resume to continue"


def journal_path(*outputs: Path | None) -> Path | None:
    """Where a study's journal lives: beside the first output given (``out.json``:
    ``out.journal.jsonl``); None when the study writes no file."""
    for output in outputs:
        if output is not None:
            return output.with_suffix(".journal.jsonl")
    return None


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


def header_of(study: Study, files: Iterable[str]) -> JournalHeader:
    """The journal header of ``study`` (cut in chunks of its ``batch`` trials) whose tasks read
    ``files`` (:func:`provenance.study_files`), its parameters as JSON gives them back (tuples as
    lists), so that a header read from a journal compares equal."""
    parameters = msgspec.json.decode(msgspec.json.encode(dict(study.parameters)))
    return JournalHeader(experiment=study.experiment, batch=study.batch, parameters=parameters,
                         inputs=inputs_digest(parameters, files))


def inputs_digest(parameters: Mapping[str, object], files: Iterable[str] = ()) -> str:
    """What a study's results depend on besides its parameters' values, as a SHA-256 (hex): the
    source of the code that computes them (:func:`code_digest`), the contents of every file the
    ``parameters`` name (a scenario's TOML, a strategy's Python file) and of the other ``files``
    its tasks read (:func:`provenance.study_files`: strategy files a scenario names)."""
    digest = hashlib.sha256(code_digest().encode())
    for name in sorted(set(named_files(parameters)).union(files)):
        digest.update(f"{name}\0{file_digest(name)}\0".encode())
    return digest.hexdigest()


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
