"""Putting on the bus the samples of the participants that share one event loop.

A process that hosts several participants (robots packed into one process) runs them on one loop,
and a burst of samples wakes several of them in one loop iteration. Their puts are held until that
iteration is over and then made back to back: Zenoh's thread is woken once for the burst rather
than once a put, and the Python thread does not trade the interpreter lock with Zenoh's thread at
every put (a put releases the lock while Zenoh queues the sample, and Zenoh's thread takes it to
run a callback). A loop with a single participant puts at once: it has nothing to batch, and
holding a put would only delay it.
"""

from __future__ import annotations

import asyncio
import logging

import zenoh

from ringtrack.bus.perloop import PerLoop

log = logging.getLogger(__name__)


class Outbox(PerLoop):
    """The puts of the participants of one event loop (see the module's text; one per loop,
    :meth:`PerLoop.of`, each participant a user); :meth:`release` as each closes puts what is held."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        super().__init__(loop)
        self._held: list[tuple[zenoh.Publisher, bytes, bytes | None]] = []

    def put(self, publisher: zenoh.Publisher, payload: bytes, attachment: bytes | None = None) -> None:
        """Put ``payload`` (with ``attachment``, the sender's life) with ``publisher``: at once when
        the loop has one participant, else once the loop's current iteration is over (in the order of
        the calls)."""
        if self.users < 2:
            publisher.put(payload, attachment=attachment)
            return
        self._held.append((publisher, payload, attachment))
        if len(self._held) == 1:
            self._loop.call_soon(self.flush)

    def flush(self) -> None:
        """Put everything held, in order; a put that fails is logged and the others still go."""
        held, self._held = self._held, []
        for publisher, payload, attachment in held:
            try:
                publisher.put(payload, attachment=attachment)
            except Exception:  # pragma: no cover - a closed session; the rest must not be lost
                log.exception("a held put failed")

    def release(self) -> bool:
        """A participant of the loop closes: put what is held (its publishers are still declared)."""
        self.flush()
        return super().release()
