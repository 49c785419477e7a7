"""Shared console output: results on stdout, progress and errors on stderr, JSON files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rich.console import Console

out = Console()
# soft_wrap: a one-line message stays one line whatever the terminal width (errors are grepped).
err = Console(stderr=True, soft_wrap=True)


class UsageError(ValueError):
    """A command-line value is unusable; the message is one line naming the flag and the fix."""


def write_json(path: Path, data: Any) -> None:
    """Write ``data`` as indented JSON, creating the parent folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2) + "\n")
