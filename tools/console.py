"""Shared console output: results on stdout, progress and errors on stderr, JSON files."""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from rich.console import Console

out = Console()
# soft_wrap: a one-line message stays one line whatever the terminal width (errors are grepped).
err = Console(stderr=True, soft_wrap=True)


SUMMARISED_ABOVE = 20  # robots (or links) from which a table shows min/median/max and the busiest only
BUSIEST = 5  # rows of the busiest robots (or links) such a summary keeps


class UsageError(ValueError):
    """A command-line value is unusable; the message is one line naming the flag and the fix."""


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON, creating the parent folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")


def write_csv(path: Path, rows: Iterable[Mapping[str, Any]], columns: list[str]) -> int:
    """Write ``rows`` as CSV with a header of ``columns`` (None as an empty cell), creating the parent
    folder; returns the rows written. Any CSV reader loads it (``pandas.read_csv``, ``readtable``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow(row)
            count += 1
    return count
