"""One robot id, one process: a second process that claims a live robot's id is refused at start,
and a collision that slips through (two processes starting at the same instant) is seen by both.

Zenoh merges liveliness tokens of the same key: a second ``alive/r3`` token is invisible while the
first is up, and the first one's departure is then not seen either. So a robot asks, before it
declares its own ``alive`` token, whether one of its name is already up, and it also holds a claim
token ``claim/<name>/<session id>`` of a key no other session can hold, watching its name's claims
for any other session's for as long as it runs.
"""

from __future__ import annotations

import asyncio
import logging

import zenoh

from ringtrack.bus.keys import WORLD
from ringtrack.bus.participant import Participant

log = logging.getLogger(__name__)

WORLD_WAIT_S = 2.0  # how long to wait for the world's token before asking (a robot started before the world)
SETTLE_S = 1.0  # after the world's token: how long the session may take to link to the other peers


class IdCollision(ValueError):
    """Another live process already runs as this participant; the message says which and what to do."""


def token_names(participant: Participant, key_expr: str) -> set[str]:
    """The last key segment of every liveliness token of ``key_expr`` the session can see now."""
    replies = participant.session.liveliness().get(key_expr, timeout=1.0)
    return {str(reply.ok.key_expr).rsplit("/", 1)[-1] for reply in replies if reply.ok is not None}


async def refuse_if_alive(participant: Participant, neighbours: set[str]) -> None:
    """Raise :class:`IdCollision` when a participant named as this one is alive in the run (its
    ``alive`` token is up). Call before declaring this one's own token.

    A peer sees only the tokens of the peers it has linked to, and links to the others (gossip)
    some 0.1 s after reaching the world. So it asks until it sees its own name (refused), or the
    world and both ``neighbours`` (linked), or ``SETTLE_S`` after it first saw the world; it gives up
    after ``WORLD_WAIT_S`` without the world (no run reached: the claim watch of :class:`IdClaim`
    remains)."""
    loop = asyncio.get_running_loop()
    started, world_seen = loop.time(), None
    while True:
        names = token_names(participant, participant.keys.alive())
        if participant.name in names:
            raise IdCollision(f"{participant.name} is already alive in run {participant.keys.run:08x} (its liveliness "
                              "token is up); stop that process first, or give an id no live robot has")
        now = loop.time()
        if WORLD in names:
            world_seen = world_seen or now
            if neighbours <= names or now - world_seen > SETTLE_S:
                return
        elif now - started > WORLD_WAIT_S:
            return
        await asyncio.sleep(0.05)


class IdClaim:
    """Holds this session's claim on ``participant.name`` and records every other session that
    claims the same name (``rivals``, Zenoh session ids), warning once for each."""

    def __init__(self, participant: Participant) -> None:
        session = participant.session
        self.name = participant.name
        self.zid = str(session.zid())
        self.rivals: set[str] = set()
        keys = participant.keys
        self._token = session.liveliness().declare_token(keys.claim(participant.name, self.zid))
        self._subscriber = session.liveliness().declare_subscriber(
            keys.claim(participant.name), zenoh.handlers.Callback(self._on_claim, indirect=False), history=True)

    def _on_claim(self, sample: zenoh.Sample) -> None:
        zid = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind == zenoh.SampleKind.PUT and zid != self.zid and zid not in self.rivals:
            self.rivals.add(zid)
            log.warning("%s: another process (Zenoh session %s) also runs as %s: an id collision; this run's "
                        "results cannot be trusted", self.name, zid, self.name)

    def close(self) -> None:
        for entity in (self._subscriber, self._token):
            try:
                entity.undeclare()
            except Exception:  # pragma: no cover - the session may already be closed
                pass
