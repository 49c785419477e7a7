"""The ``relay`` strategy: the paper's self-triggered triggers, every message carrying ranges."""

from __future__ import annotations

from ringtrack.agents.strategy import SelfTriggered


class RelayedRanges(SelfTriggered):
    """Self-triggered polling; requests and replies carry the ranges their sender holds (:mod:`agents.relay`)."""

    name = "relay"
    summary = "self-triggered, every request and reply carrying the ranges its sender holds"
    label = "relayed ranges"
    estimation = "decentralized"
    relays = True
