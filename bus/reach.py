"""Who can reach whom, as liveliness tokens ``reach/<observed>/<observer>``.

A session declares its subscriptions before its ``alive`` token, and Zenoh sends a session's
declarations over a link in order; so a participant that sees another's ``alive`` token has a link to
it and can send to it. It says so with the token ``reach/<observed>/<observer>``:

* the world holds one for every robot whose ``alive`` token it sees: a robot about to start asks for
  its own name's (:func:`bus.identity.refuse_if_alive`), and the world's own tokens reach a joining
  process over its first link, whatever the load;
* a robot holds one for every robot it sees alive outside its ring (one coming back) and, while it is
  outside the ring itself, for every participant it sees alive: the world re-admits a robot once it
  and its future ring neighbours reach one another (:mod:`world.admission`).
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass

import zenoh

from ringtrack.bus.participant import Participant, Posted

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Reach(Posted):
    """``observer`` sees (``up``) or no longer sees ``observed``'s ``alive`` token."""

    observer: str
    observed: str
    up: bool


class ReachTokens:
    """The ``reach`` tokens ``participant`` holds, one per participant it says it sees."""

    def __init__(self, participant: Participant) -> None:
        self.participant = participant
        self._tokens: dict[str, zenoh.LivelinessToken] = {}

    @property
    def held(self) -> set[str]:
        return set(self._tokens)

    def hold(self, observed: set[str]) -> None:
        """Hold exactly the tokens for the names ``observed``: declare the new, withdraw the others."""
        for name in set(self._tokens) - observed:
            with contextlib.suppress(Exception):  # the session may already be closed
                self._tokens.pop(name).undeclare()
        keys, liveliness = self.participant.keys, self.participant.session.liveliness()
        for name in sorted(observed - set(self._tokens)):
            self._tokens[name] = liveliness.declare_token(keys.reach(name, self.participant.name))

    def close(self) -> None:
        self.hold(set())


class ReachWatch:
    """Posts a :class:`Reach` event to ``participant``'s inbox for every ``reach`` token of the run
    that appears or goes (current ones first)."""

    def __init__(self, participant: Participant) -> None:
        self.participant = participant
        self._subscriber = participant.session.liveliness().declare_subscriber(
            participant.keys.reach(), zenoh.handlers.Callback(self._on_token, indirect=False), history=True)

    def _on_token(self, sample: zenoh.Sample) -> None:
        try:
            observed, observer = str(sample.key_expr).split("/")[-2:]
            self.participant.inbox.push(Reach(observer, observed, sample.kind == zenoh.SampleKind.PUT))
        except Exception:  # pragma: no cover - a failing callback must never go silent
            self.participant.callback_failures += 1
            log.exception("reach callback failed")

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._subscriber.undeclare()
