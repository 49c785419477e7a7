"""The neighbour round trip on its own: robot r0 polls robot r1, r1 answers, as in a poll.

Two processes, started by ``ringtrack bench latency`` (``python -m ringtrack.tools.bench.latency ping|echo``), join a
two-robot run on the embedded bus and exchange real :class:`~bus.messages.Request` and
:class:`~bus.messages.Reply` messages through :class:`bus.participant.Participant`, the path every
poll takes. ``ping`` times each round trip (wall seconds, ``time.perf_counter``); both sides measure
the CPU seconds their process spent (all threads, Zenoh's included) over the timed rounds, and write
their results as JSON.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import secrets
import sys
import time
from pathlib import Path

from ringtrack.bus.config import BusConfig, announce_endpoints
from ringtrack.bus.keys import Keys, robot_name
from ringtrack.bus.messages import SCHEMA, Reply, Request
from ringtrack.bus.participant import Delivery, Interrupt, Participant
from ringtrack.bus.runtime import Interrupts, Roster, gather_until, joined, linger

PINGER, ECHO = 0, 1
ROBOTS = 2


async def ping(bus: BusConfig, run: int, rounds: int, warmup: int, result: Path) -> int:
    """Poll r1 ``warmup + rounds`` times, one request at a time; write the timed round trips (s)."""
    keys = Keys(run)
    async with joined(bus, keys, robot_name(PINGER), ROBOTS, Interrupts(exit_with_parent=True)) as participant:
        participant.listen(keys.inbox(robot_name(PINGER)))
        participant.watch("alive")
        participant.announce("alive")
        roster = Roster()
        echo = robot_name(ECHO)
        if not (await gather_until(participant, roster, lambda: echo in roster.alive))[0]:
            return 130
        round_trips: list[float] = []
        cpu_started = 0.0
        for step in range(1, warmup + rounds + 1):
            if step == warmup + 1:
                cpu_started = time.process_time()
            nonce = secrets.randbits(32)
            sent = time.perf_counter()
            participant.send(echo, Request(SCHEMA, run, step, PINGER, ECHO, nonce))
            if not await _answered(participant, nonce):
                return 130
            if step > warmup:
                round_trips.append(time.perf_counter() - sent)
        cpu_s = time.process_time() - cpu_started
        result.write_text(json.dumps({"round_trips_s": round_trips, "cpu_s": cpu_s}))
        await linger(participant, roster, {echo})
        return 0


async def _answered(participant: Participant, nonce: int) -> bool:
    while True:
        for event in await participant.events():
            if isinstance(event, Interrupt):
                return False
            if isinstance(event, Delivery) and isinstance(event.message, Reply) and event.message.nonce == nonce:
                return True


async def echo(bus: BusConfig, run: int, rounds: int, warmup: int, result: Path) -> int:
    """Answer r0's requests with a reply; write the CPU seconds spent on the timed rounds. Announces
    its endpoints in ``result.endpoints.json`` first (it listens on a free port)."""
    keys = Keys(run)
    async with joined(bus, keys, robot_name(ECHO), ROBOTS, Interrupts(exit_with_parent=True)) as participant:
        participant.listen(keys.inbox(robot_name(ECHO)))
        participant.announce("alive")
        announce_endpoints(participant.session, endpoints_path(result))
        cpu_started = 0.0
        answered = 0
        while answered < warmup + rounds:
            for event in await participant.events():
                if isinstance(event, Interrupt):
                    return 130
                if isinstance(event, Delivery) and isinstance(event.message, Request):
                    request = event.message
                    if answered == warmup:
                        cpu_started = time.process_time()
                    participant.send(robot_name(request.sender), Reply(
                        SCHEMA, run, request.step, ECHO, request.sender, request.nonce, (0.0, 0.0)))
                    answered += 1
        result.write_text(json.dumps({"cpu_s": time.process_time() - cpu_started}))
        return 0


def endpoints_path(result: Path) -> Path:
    return result.with_suffix(".endpoints.json")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ringtrack.tools.bench.latency")
    parser.add_argument("side", choices=["ping", "echo"])
    parser.add_argument("--run", type=lambda text: int(text, 16), required=True)
    parser.add_argument("--rounds", type=int, required=True)
    parser.add_argument("--warmup", type=int, required=True)
    parser.add_argument("--result", type=Path, required=True)
    parser.add_argument("--connect", action="append", default=[])
    args = parser.parse_args(argv)
    bus = BusConfig(connect=tuple(args.connect), admin_space=args.side == "echo")
    side = ping if args.side == "ping" else echo
    return asyncio.run(side(bus, args.run, args.rounds, args.warmup, args.result))


if __name__ == "__main__":
    sys.exit(main())
