"""Fenced lives: every life of a robot id has a number that grows each time the id rejoins.

A robot frozen past the liveliness lease is seen gone; a new process may then join under its id.
When the old one wakes, two processes would act as one robot. So the world, which outlives them
both, grants each process a *life* number when it joins (a Zenoh query on ``life/<name>``,
answered with the next number of that name, 1 for the first). The process stamps its life on every
message it sends (the sample's attachment, :func:`bus.participant.life_attachment`), and every receiver drops and
counts as ``"superseded"`` a message from a life older than the newest it has seen of that sender
(:meth:`bus.participant.Participant.accept`). The life is also part of the process's claim token
(:mod:`bus.identity`): a process that sees a claim of its name by a newer life knows it was
replaced, and exits at once (:class:`Superseded`).
"""

from __future__ import annotations

import asyncio
import logging
import pickle
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, replace

import zenoh

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.bus.keys import MONITOR, WORLD, Keys
from ringtrack.bus.participant import Participant, Posted, life_attachment

log = logging.getLogger(__name__)

CURRENT = "current"  # the parameter of a query that asks for a name's newest life without taking one
CHECK_S = 2.0  # how long a lifeboat waits to see a participant, and for the world's answer
LEAVE_S = 0.1  # how long a lifeboat stays open after its last put
VOYAGE_LIMIT_S = 10.0  # the longest a lifeboat process may take (it starts in about 0.3 s)
ASK_EVERY_S = 0.5  # how often a joining robot asks again while no world answers
ASK_LIMIT_S = 60.0  # ... and for how long at most


class NoLife(ValueError):
    """No world of the run granted this process a life; the message says what to do."""


class Superseded(ValueError):
    """This process's life of a robot id was replaced by a newer one (it was seen gone and the id
    rejoined); the message names the id, the run and both lives. The process must stop at once."""


@dataclass(frozen=True)
class NewerLife(Posted):
    """Posted to a participant's inbox when a claim of its name by a newer ``life`` appears."""

    life: int


def life_label(name: str, life: int) -> str:
    """How books name one life of a participant: ``name`` for its first (or only) life, else
    ``<name>.life<n>``."""
    return name if life <= 1 else f"{name}.life{life}"


SUPERSEDED_MARK = "was replaced by life"  # what the line of a replaced process says (a supervisor reads it)


def superseded_message(name: str, run: int, life: int, newer: int) -> str:
    """The one line a replaced process stops with."""
    return (f"{name} (life {life}) of run {run:08x} {SUPERSEDED_MARK} {newer} of {name} (it was seen gone and "
            "its id rejoined); this process stops")


class LifeRegistry:
    """The world's grants: the newest life of every robot name, answering ``life/<name>`` queries.

    A query's answer is the next number of that name; the participant's ``lives`` (what its door
    checks) learns it at once, so a command of the life before is refused from the first grant on.
    A query ``life/<name>?current`` is answered with the newest life granted (0: none), taking none."""

    def __init__(self, participant: Participant) -> None:
        self.participant = participant
        self._lock = threading.Lock()
        self.granted: dict[str, int] = {}
        self._queryable = participant.session.declare_queryable(
            participant.keys.life(), zenoh.handlers.Callback(self._on_query, indirect=False))

    def _on_query(self, query: zenoh.Query) -> None:
        try:
            name = str(query.key_expr).rsplit("/", 1)[-1]
            if not name or name == "*":
                return
            with self._lock:
                if str(query.parameters) == CURRENT:  # who holds the name now: nothing granted
                    query.reply(query.key_expr, str(self.granted.get(name, 0)).encode())
                    return
                life = self.granted.get(name, 0) + 1
                self.granted[name] = life
                self.participant.lives[name] = life
            query.reply(query.key_expr, str(life).encode())
            if life > 1:
                log.info("%s joins as life %d of %s", name, life, name)
        except Exception:  # pragma: no cover - a failing callback must never go silent
            log.exception("life query failed")

    def close(self) -> None:
        try:
            self._queryable.undeclare()
        except Exception:  # pragma: no cover - the session may already be closed
            pass


class Lifeboat:
    """A fresh Zenoh session for a robot process whose own is cut off: one woken after a freeze past
    the lease finds every link closed, and its process's Zenoh runtime may take seconds to link
    again (longer than the others take to be sure it is gone). So the lifeboat runs in a short-lived
    process of its own (:func:`row_out`), through which the process asks whether a newer life of its
    id was granted meanwhile (:meth:`newest_life`) and, once replaced, sends its last statistics
    (its books) to the monitor (:meth:`send`). Its methods block, each at most about
    :data:`CHECK_S`."""

    def __init__(self, bus: BusConfig, keys: Keys, name: str) -> None:
        self.keys = keys
        self.name = name
        self.session = open_session(replace(bus, listen=()), name)

    def sees(self, other: str, limit_s: float = CHECK_S) -> bool:
        """Whether ``other``'s alive token shows up on this session within ``limit_s`` seconds."""
        deadline = time.monotonic() + limit_s
        while True:
            replies = self.session.liveliness().get(self.keys.alive(other), timeout=min(0.25, limit_s))
            if any(reply.ok is not None for reply in replies):
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)

    def newest_life(self) -> int | None:
        """The newest life of this name the run's world has granted; None when no world answers."""
        if not self.sees(WORLD):
            return None
        for reply in self.session.get(f"{self.keys.life(self.name)}?{CURRENT}", timeout=CHECK_S):
            if reply.ok is not None:
                return int(reply.ok.payload.to_bytes())
        return None

    def send(self, destination: str, kind: str, payload: bytes, life: int) -> bool:
        """Put a ``kind`` message's ``payload`` to ``destination`` stamped with ``life`` once
        ``destination`` is seen; whether it was."""
        if not self.sees(destination):
            return False
        self.session.put(self.keys.data(destination, self.name, kind), payload, attachment=life_attachment(life))
        return True

    def close(self) -> None:
        """Close the session, after its last put had time to leave."""
        time.sleep(LEAVE_S)
        self.session.close()


@dataclass(frozen=True)
class Voyage:
    """What a lifeboat process is asked: for ``name``'s newest life in run ``run`` (reached with
    ``bus``), and, if a newer life than ``life`` replaced it, to hand ``books`` (an encoded final
    :class:`bus.messages.Stats`, or None) to the monitor."""

    bus: BusConfig
    run: int
    name: str
    life: int
    books: bytes | None = None


def row_out(voyage: Voyage) -> int | None:
    """Run a lifeboat process for ``voyage`` (blocking, at most :data:`VOYAGE_LIMIT_S`); returns the
    newest life of the name the world granted, None when no world answered."""
    try:
        done = subprocess.run([sys.executable, "-m", "ringtrack.bus.lives"], input=pickle.dumps(voyage),
                              capture_output=True, timeout=VOYAGE_LIMIT_S, check=False)
    except subprocess.TimeoutExpired:
        return None
    answer = done.stdout.strip()
    return int(answer) if done.returncode == 0 and answer.isdigit() else None


def sail(voyage: Voyage) -> int | None:
    """The lifeboat process's work (:func:`row_out`)."""
    boat = Lifeboat(voyage.bus, Keys(voyage.run), voyage.name)
    try:
        newest = boat.newest_life()
        if voyage.books is not None and (newest is None or newest > voyage.life):
            boat.send(MONITOR, "stats", voyage.books, voyage.life)
        return newest
    finally:
        boat.close()


async def ask_life(participant: Participant, limit_s: float = ASK_LIMIT_S) -> int:
    """Ask the run's world for a life of ``participant.name``; returns its number. Raises
    :class:`NoLife` when no world answers within ``limit_s`` seconds."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + limit_s
    key = participant.keys.life(participant.name)
    while True:
        replies = await asyncio.to_thread(lambda: list(participant.session.get(key, timeout=ASK_EVERY_S)))
        for reply in replies:
            if reply.ok is not None:
                return int(reply.ok.payload.to_bytes())
        if loop.time() >= deadline:
            raise NoLife(f"{participant.name}: no world of run {participant.keys.run:08x} granted a life within "
                         f"{limit_s:g} s; start the world first (or check --connect)")
        await asyncio.sleep(ASK_EVERY_S)


if __name__ == "__main__":  # a lifeboat process (row_out): a pickled Voyage on stdin, the newest life on stdout
    print(sail(pickle.loads(sys.stdin.buffer.read())) or "")
