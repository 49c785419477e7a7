"""What a monitor keeps on disk so that a monitor restarted in the same run resumes its log and books.

While it runs, the monitor writes its tallies to ``<log>.checkpoint.json`` next to the run log
every ``CHECKPOINT_PERIOD_S`` (whole, then renamed: a killed monitor leaves the previous one), and
removes it once the log has its end record. A monitor started with ``--resume`` reads it back, goes
on writing the same log after its last complete step, and takes the steps it misses from the
world's replay (:mod:`world.backlog`): in lockstep without the audit, where the world's digests
account for every robot-to-robot, measurement and command message, the books then close exactly as
if the monitor had never gone; what a monitor observes itself on the wire (with ``--audit``, or in
realtime) between its last checkpoint and its return it cannot have seen, and its books name those
messages as unobserved (:func:`bus.counting.close_books`).
"""

from __future__ import annotations

import contextlib
import os
from collections import Counter
from pathlib import Path

import msgspec

from ringtrack.bus.counting import TrafficCounter
from ringtrack.bus.messages import Stats, Traffic

CHECKPOINT_PERIOD_S = 0.25


class Checkpoint(msgspec.Struct, frozen=True):
    """A monitor's tallies at one moment: ``digested_through`` is the last step whose digest entries
    were counted; ``received``/``rejected`` the monitor's own counts, ``fenced`` those of replaced
    lives dropped at its door; ``finals`` the final statistics in so far (by life label), ``cut_off``
    who left during the run, ``lives`` and ``life_history`` each sender's newest and every life seen,
    ``lives_recorded`` how many of those the log has life events for."""

    run: str
    digested_through: int
    latest_tick: int
    late: int
    dropped_ahead: int
    received: list[Traffic]
    rejected: dict[str, int]
    fenced: list[Traffic]
    finals: dict[str, Stats]
    cut_off: list[str]
    lives: dict[str, int]
    life_history: dict[str, list[int]]
    lives_recorded: dict[str, int]


def checkpoint_path(log_path: Path) -> Path:
    """Where the monitor writing ``log_path`` keeps its checkpoint."""
    return log_path.with_name(f"{log_path.stem}.checkpoint.json")


def write_checkpoint(path: Path, checkpoint: Checkpoint) -> None:
    """Write ``checkpoint`` to ``path`` whole, then rename it into place; best effort (a full disk
    keeps the previous one and leaves no partial file)."""
    partial = path.with_name(f"{path.name}.partial")
    try:
        partial.write_bytes(msgspec.json.encode(checkpoint))
        os.replace(partial, path)
    except OSError:
        with contextlib.suppress(OSError):
            partial.unlink()


def read_checkpoint(path: Path, run: str) -> Checkpoint | None:
    """The checkpoint at ``path`` of run ``run`` (hex), or None: none written, unreadable, or
    another run's."""
    try:
        checkpoint = msgspec.json.decode(path.read_bytes(), type=Checkpoint)
    except (OSError, msgspec.ValidationError, msgspec.DecodeError):
        return None
    return checkpoint if checkpoint.run == run else None


def restore_counts(counter: TrafficCounter, rows: list[Traffic], rejected: dict[str, int] | None = None) -> None:
    """Add the received ``rows`` (and ``rejected`` payloads by reason) to ``counter``."""
    for kind, source, destination, messages, size in rows:
        counter.received_messages[kind, source, destination] += messages
        counter.received_bytes[kind, source, destination] += size
    counter.rejected.update(Counter(rejected or {}))
