"""The steps a world keeps for a monitor that may come back, and the hold while it is away.

A run whose monitor may be restarted (``world --monitor-grace S``: a nemesis plan that kills the
monitor and restarts it) does not end when its monitor goes away: the world finishes the step it is
in and then holds the run, publishing nothing, until a monitor is back or ``S`` seconds have passed
(then it ends the run as :attr:`~bus.messages.EndReason.MONITOR_LOST`). Meanwhile it keeps the last
``BACKLOG_STEPS`` steps as digest entries; the moment a monitor is back, it sends them to it in
:class:`~bus.messages.Digest` messages marked ``replayed``, from which the monitor that resumes the
run log (``monitor --resume``) writes the steps its predecessor had not written and counts the
messages its predecessor had not counted. A step's entries go to the monitor either in the replay
or in the ordinary digests that follow it, never in both.
"""

from __future__ import annotations

from collections import deque

from ringtrack.bus.keys import MONITOR
from ringtrack.bus.messages import SCHEMA, Command, Digest, DigestEntry, Tick, digest_entries
from ringtrack.bus.participant import Participant

BACKLOG_STEPS = 4096  # digest entries a world keeps for a returning monitor (a step of a team of six: ~1 KiB)

Measurements = list[tuple[int, int]]  # (robot, payload bytes) of the measurements of a step


def step_entries(step: int, tick: Tick | None, measurements: Measurements, commands: list[tuple[Command, int]],
                 team: int) -> list[DigestEntry]:
    """The digest entries of ``step``: its tick, measurements and at most ``team`` commands (with
    their payload bytes) in the first, further commands ``team`` to an entry after it."""
    entries = [DigestEntry(step, tick, measurements, commands[:team])]
    entries += [DigestEntry(step, None, [], commands[first:first + team]) for first in range(team, len(commands), team)]
    return entries


class Backlog:
    """The last ``BACKLOG_STEPS`` digest entries of a run, to replay to a monitor that came back."""

    def __init__(self, participant: Participant) -> None:
        self.participant = participant
        self.entries: deque[DigestEntry] = deque(maxlen=BACKLOG_STEPS)

    def add(self, entries: list[DigestEntry]) -> None:
        self.entries.extend(entries)

    def replay(self) -> int:
        """Send every entry kept to the monitor, oldest first, in digests marked ``replayed``;
        returns how many entries were sent."""
        kept = list(self.entries)
        limit = digest_entries(self.participant.robots)
        for first in range(0, len(kept), limit):
            self.participant.send(MONITOR, Digest(SCHEMA, self.participant.keys.run, kept[first:first + limit],
                                                  replayed=True))
        return len(kept)
