"""One robot id, one process: a second process that claims a live robot's id is refused at start,
and a collision that slips through (two processes starting at the same instant) is seen by both.

Zenoh merges liveliness tokens of the same key: a second ``alive/r3`` token is invisible while the
first is up, and the first one's departure is then not seen either. So a robot asks, before it
declares its own ``alive`` token, whether the world sees one of its name (the world's
``reach/<name>/world`` token, :mod:`bus.reach`, which reaches a joining process over its first link,
whatever the load) or whether it sees one itself; it also holds a claim token
``claim/<name>/<life>-<session id>`` of a key no other session can hold, watching its name's claims
for as long as it runs: another session's claim of the same life is a collision, one of a newer life
(the world granted the id again after this process was seen gone: :mod:`bus.lives`) means this
process was replaced, and it is told so through its inbox (:class:`bus.lives.NewerLife`).
"""

from __future__ import annotations

import asyncio
import logging

import zenoh

from ringtrack.bus.keys import WORLD
from ringtrack.bus.lives import NewerLife
from ringtrack.bus.participant import Participant

log = logging.getLogger(__name__)

WORLD_WAIT_S = 2.0  # how long to wait for the world's token before going on (a robot started before the world)


class IdCollision(ValueError):
    """Another live process already runs as this participant; the message says which and what to do."""


def token_names(participant: Participant, key_expr: str) -> set[str]:
    """The last key segment of every liveliness token of ``key_expr`` the session can see now."""
    replies = participant.session.liveliness().get(key_expr, timeout=1.0)
    return {str(reply.ok.key_expr).rsplit("/", 1)[-1] for reply in replies if reply.ok is not None}


async def refuse_if_alive(participant: Participant) -> None:
    """Raise :class:`IdCollision` when a participant named as this one is alive in the run. Call
    before declaring this one's own token.

    A peer sees only the tokens of the peers it has linked to, and links to the others (gossip)
    some time after reaching the world, later under load. So it waits until it sees the world (at
    most ``WORLD_WAIT_S``: no run reached, the claim watch of :class:`IdClaim` remains), then asks
    for the world's ``reach`` token of its name and for an ``alive`` token of its name."""
    loop = asyncio.get_running_loop()
    started = loop.time()
    keys, name = participant.keys, participant.name
    while WORLD not in token_names(participant, keys.alive(WORLD)) and loop.time() - started < WORLD_WAIT_S:
        await asyncio.sleep(0.05)
    if token_names(participant, keys.reach(name, WORLD)) or name in token_names(participant, keys.alive(name)):
        raise IdCollision(f"{name} is already alive in run {keys.run:08x} (its liveliness token is up); stop that "
                          "process first, or give an id no live robot has")


class IdClaim:
    """Holds this session's claim on ``participant.name`` as its life ``participant.life`` and
    records every other session that claims the same name as the same life (``rivals``, Zenoh
    session ids), warning once for each; a claim by a newer life posts :class:`bus.lives.NewerLife`
    to the participant's inbox (``newer``: the newest such life seen, 0 while none). A claim of an
    older life is that life's process, fenced: it stops as soon as it sees this one's claim."""

    def __init__(self, participant: Participant) -> None:
        session = participant.session
        self.participant = participant
        self.name = participant.name
        self.zid = str(session.zid())
        self.life = participant.life
        self.rivals: set[str] = set()
        self.newer = 0
        keys = participant.keys
        self._token = session.liveliness().declare_token(keys.claim(participant.name, f"{self.life}-{self.zid}"))
        self._subscriber = session.liveliness().declare_subscriber(
            keys.claim(participant.name), zenoh.handlers.Callback(self._on_claim, indirect=False), history=True)

    def _on_claim(self, sample: zenoh.Sample) -> None:
        life_text, _, zid = str(sample.key_expr).rsplit("/", 1)[-1].partition("-")
        if sample.kind != zenoh.SampleKind.PUT or zid == self.zid or not life_text.isdigit():
            return
        self.newer_life(int(life_text))
        if int(life_text) == self.life and zid not in self.rivals:
            self.rivals.add(zid)
            log.warning("%s: another process (Zenoh session %s) also runs as %s: an id collision; this run's "
                        "results cannot be trusted", self.name, zid, self.name)

    def newer_life(self, life: int) -> None:
        """Post :class:`bus.lives.NewerLife` once for each life of this name newer than any seen
        (any thread)."""
        if life > max(self.life, self.newer):
            self.newer = life
            self.participant.inbox.push(NewerLife(life))

    def close(self) -> None:
        for entity in (self._subscriber, self._token):
            try:
                entity.undeclare()
            except Exception:  # pragma: no cover - the session may already be closed
                pass
