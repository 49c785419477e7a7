"""Shared console output: results on stdout, progress and errors on stderr, JSON files."""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
from rich.console import Console, RenderableType
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ringtrack.world.scenario import Scenario
from ringtrack.world.threshold import loose_threshold

if TYPE_CHECKING:
    from rich.progress import Progress

out = Console()
# soft_wrap: a one-line message stays one line whatever the terminal width (errors are grepped).
err = Console(stderr=True, soft_wrap=True)


UNBOUNDED_WIDTH = 10_000  # columns a table may take off a terminal (a pipe or a file has no width)
SUMMARISED_ABOVE = 20  # robots (or links) from which a table shows min/median/max and the busiest only
BUSIEST = 5  # rows of the busiest robots (or links) such a summary keeps


class UsageError(ValueError):
    """A command-line value is unusable; the message is one line naming the flag and the fix."""


class OutputError(ValueError):
    """An output file could not be written (a full disk, a read-only folder); the message is one
    line naming the file and why. Not bad input: the command exits with ``exit_code``."""

    exit_code = 1


def show(renderable: RenderableType, console: Console | None = None) -> None:
    """Print a table (or any renderable) on ``console`` (default stdout), never cut: on a terminal at
    its width; off one (a pipe, a file: no width of its own) at the width the table needs, wider
    than the console if need be. A column of prose that should wrap says so with ``max_width``."""
    console = console or out
    if console.is_terminal:
        console.print(renderable)
        return
    unbounded = console.options.update(width=UNBOUNDED_WIDTH, max_width=UNBOUNDED_WIDTH)
    needed = min(Measurement.get(console, unbounded, renderable).maximum, UNBOUNDED_WIDTH)
    width = console.width
    if needed <= width:
        console.print(renderable)
        return
    console.width = needed  # a console never prints wider than itself
    try:
        console.print(renderable)
    finally:
        console.width = width


def progress_bar(console: Console | None = None, disable: bool = False) -> Progress:
    """The progress display of a long command: on ``console`` (default stderr), one bar per task with
    its count done and the time elapsed; ``disable`` shows nothing at all."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=console or err, disable=disable)


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` (plain values, msgspec structs, enums) as indented JSON, creating the parent
    folder. Atomic: the file is written whole under a temporary name and renamed, so a full disk
    leaves either the complete file or none (never a torn one) and raises :class:`OutputError`
    saying why."""
    temporary = path.with_name(f".{path.name}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary.write_text(json.dumps(msgspec.to_builtins(data), indent=2) + "\n")
        os.replace(temporary, path)
    except OSError as error:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise OutputError(f"{path}: not written ({error.strerror or error})") from None


def write_csv(path: Path, rows: Iterable[msgspec.Struct | Mapping[str, Any]], columns: list[str]) -> int:
    """Write ``rows`` (msgspec structs, or mappings) as CSV with a header of ``columns`` (a row
    type's: :func:`struct_columns`; None as an empty cell), creating the parent folder; returns the
    rows written. Any CSV reader loads it (``pandas.read_csv``, ``readtable``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow(msgspec.structs.asdict(row) if isinstance(row, msgspec.Struct) else row)
            count += 1
    return count


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


def warn_if_threshold_loose(scenario: Scenario) -> None:
    """One warning line on stderr when the scenario's convergence threshold is too loose to mean
    anything for its team size (:func:`world.threshold.loose_threshold`)."""
    problem = loose_threshold(math.degrees(scenario.threshold), scenario.robots)
    if problem is not None:
        err.print(f"ringtrack: warning: {problem}", highlight=False, markup=False)
