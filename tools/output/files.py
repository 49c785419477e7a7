"""Files a command writes: JSON and CSV written whole or not at all, and checks made before any work."""

from __future__ import annotations

import contextlib
import csv
import json
import os
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

import msgspec


class OutputError(ValueError):
    """An output file could not be written (a full disk, a read-only folder); the message is one
    line naming the file and why. Not bad input: the command exits with ``exit_code``."""

    exit_code = 1


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` (plain values, msgspec structs, enums) as indented JSON, creating the parent
    folder, whole or not at all (:func:`written_whole`)."""
    with written_whole(path) as file:
        file.write(json.dumps(msgspec.to_builtins(data), indent=2) + "\n")


def write_csv(path: Path, rows: Iterable[msgspec.Struct | Mapping[str, Any]], columns: list[str]) -> int:
    """Write ``rows`` (msgspec structs, or mappings) as CSV with a header of ``columns`` (a row
    type's: :func:`struct_columns`; None as an empty cell), creating the parent folder, whole or not
    at all (:func:`written_whole`); returns the rows written. Any CSV reader loads it
    (``pandas.read_csv``, ``readtable``)."""
    count = 0
    with written_whole(path) as file:
        writer = csv.DictWriter(file, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow(msgspec.structs.asdict(row) if isinstance(row, msgspec.Struct) else row)
            count += 1
    return count


@contextlib.contextmanager
def written_whole(path: Path) -> Iterator[TextIO]:
    """A text file to write ``path`` through: written under a temporary name and renamed once the
    block ends, so a full disk or a read-only folder leaves either the complete file or none (never
    a torn one) and raises :class:`OutputError` naming the file and why."""
    temporary = path.with_name(f".{path.name}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with temporary.open("w", newline="") as file:
            yield file
        os.replace(temporary, path)
    except OSError as error:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise OutputError(f"{path}: not written ({error.strerror or error})") from None
    except BaseException:  # the writer failed (or was interrupted): no half-written file is left
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def struct_columns(kind: type[msgspec.Struct], leave_out: Iterable[str] = ()) -> list[str]:
    """The CSV columns of a row type: its field names in order, but those in ``leave_out``."""
    left_out = set(leave_out)
    return [field.name for field in msgspec.structs.fields(kind) if field.name not in left_out]


def unwritable(path: Path) -> str | None:
    """Why the file ``path`` cannot be written, or None when it can: actually opened for writing
    (an existing file is neither truncated nor changed, a new one is removed again), because
    permission bits say nothing about a read-only mount or a pseudo file system such as /proc."""
    try:
        if path.exists():
            if path.is_dir():
                return "it is a folder"
            with path.open("ab"):
                pass
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("xb"):
                pass
            path.unlink()
    except OSError as error:
        return error.strerror or str(error)
    return None
