"""A passive observer of the runs on a bus: it subscribes to their keys and liveliness tokens, and
never publishes, declares no token and never holds a sender up.

Samples go into bounded Zenoh ring channels that drop the oldest when full, so an observer that
reads slowly (or not at all) loses samples itself instead of pushing back on the publishers (the
monitor's channel does push back: it must see everything). Having declared no liveliness token, it
is never taken for a participant: the world's wait for its ``--monitor`` and every roster ignore it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import TracebackType

import zenoh

from ringtrack.bus.config import BusConfig, open_session
from ringtrack.bus.keys import ROOT, Route, parse_any

CAPACITY = 1 << 16  # samples held between two polls before the oldest are dropped


@dataclass(frozen=True)
class Heard:
    """A data sample of run ``run``: its route (from the key), payload and arrival (monotonic s)."""

    run: int
    route: Route
    key: str
    payload: bytes
    at: float


@dataclass(frozen=True)
class Token:
    """Participant ``name`` of run ``run`` declared (``up``) or withdrew its ``alive`` token."""

    run: int
    name: str
    up: bool
    at: float


class Observer:
    """Watch run ``run`` (or every run when None) through the bus that ``config`` reaches."""

    def __init__(self, config: BusConfig, run: int | None = None, capacity: int = CAPACITY) -> None:
        self.prefix = f"{ROOT}/{run:08x}" if run is not None else f"{ROOT}/*"
        self.session = open_session(config)
        self.unparsed = 0  # samples whose key is not a run's data key
        try:
            self.data = self.session.declare_subscriber(f"{self.prefix}/*/*/*", zenoh.handlers.RingChannel(capacity))
            self.tokens = self.session.liveliness().declare_subscriber(
                f"{self.prefix}/alive/*", zenoh.handlers.RingChannel(4096), history=True)
        except Exception:
            self.session.close()
            raise

    def poll(self) -> list[Heard | Token]:
        """Everything that arrived since the last poll, tokens first."""
        now = time.monotonic()
        found: list[Heard | Token] = []
        while (sample := self.tokens.handler.try_recv()) is not None:
            parts = str(sample.key_expr).split("/")
            found.append(Token(int(parts[1], 16), parts[-1], sample.kind == zenoh.SampleKind.PUT, now))
        while (sample := self.data.handler.try_recv()) is not None:
            key = str(sample.key_expr)
            parsed = parse_any(key)
            if parsed is None:
                self.unparsed += 1
                continue
            found.append(Heard(parsed[0], parsed[1], key, sample.payload.to_bytes(), now))
        return found

    def close(self) -> None:
        for entity in (self.tokens, self.data):
            try:
                entity.undeclare()
            except Exception:  # pragma: no cover - the session may already be closed
                pass
        self.session.close()

    def __enter__(self) -> Observer:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()
