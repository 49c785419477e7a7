"""``ringtrack replay LOG``: watch any run again, from its log, on the live dashboard."""

from __future__ import annotations

import time
from collections.abc import Callable

from ringtrack.bus.messages import EndReason
from ringtrack.tools.monitor.state import TeamModel
from ringtrack.tools.runlog.log import RunLog

FRAME_S = 0.1  # at most ten redraws per wall second


def ending(log: RunLog) -> str:
    """The status the last frame shows: why the run ended, or that its log stops short."""
    return EndReason(log.end["reason"]).text(log.end["steps"]) if log.end else "log ends here (the run was stopped)"


def replay(model: TeamModel, records: list[dict], speed: float, refresh: Callable[[bool], None]) -> None:
    """Feed ``records`` (steps and events, in file order) to ``model``, each step at its simulated
    time over ``speed`` (simulated seconds per wall second), redrawing at most every ``FRAME_S``."""
    first = next((record["time"] for record in records if record["type"] == "step"), None)
    if first is None:
        return
    started = time.monotonic()
    last_frame = 0.0
    for record in records:
        if record["type"] == "step":
            wait = (record["time"] - first) / speed - (time.monotonic() - started)
            if wait > 0:
                time.sleep(wait)
        model.add(record)
        now = time.monotonic()
        if now - last_frame >= FRAME_S:
            refresh(False)
            last_frame = now
