"""The optional extra the Foxglove features need, and the one line that says how to install it."""

from __future__ import annotations

import importlib

from ringtrack.tools.output.console import UsageError

VIZ_EXTRA = "pip install 'ringtrack[viz]'"


def require_sdk(flag: str) -> None:
    """Raise a :class:`UsageError` naming ``flag`` and the extra to install when the Foxglove SDK
    cannot be imported (checked before any work starts)."""
    try:
        importlib.import_module("foxglove")
    except ImportError:
        raise UsageError(f"{flag} needs the Foxglove SDK, an optional extra: {VIZ_EXTRA}") from None
