"""What the role commands (world, robot, router, fusion, monitor) share: their flags and the bus they make of them."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.bus.config import LEASE_S, LOOPBACK_ANY_PORT, BusConfig
from ringtrack.bus.security import secure_config
from ringtrack.tools.cli.options import UNTIL_CONVERGED, add_scenario_arguments, positive
from ringtrack.tools.output.console import err

SECURE_HELP = "team folder made by ringtrack certs: mutual TLS on every link (tls/ endpoints), access control"


def common_flags(parser: argparse.ArgumentParser) -> None:
    add_scenario_arguments(parser, steps_help=f"run exactly this many steps (default: {UNTIL_CONVERGED}; the "
                           "world ends the run)")
    parser.add_argument("--run", type=run_id, default=0, metavar="HEX", help="run id shared by the team (hex)")
    parser.add_argument("--mode", choices=["peer", "router", "client"], default="peer", help="Zenoh mode")
    parser.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"endpoint to listen on (default {LOOPBACK_ANY_PORT}); repeatable")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT", help="endpoint to connect to; repeatable")
    parser.add_argument("--monitor", action="store_true", help="a monitor is part of the team: wait for it")
    parser.add_argument("--secure", type=Path, metavar="DIR", help=SECURE_HELP)
    lease_flag(parser)
    parser.add_argument("--audit", action="store_true",
                        help="the monitor receives a copy of every message and counts it itself (an independent "
                        "tally); by default, in lockstep, it takes the world's own counts of measurements and "
                        "commands instead; give it to the world and the monitor alike")
    parser.add_argument("--exit-with-parent", action="store_true", help=argparse.SUPPRESS)


def lease_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lease", type=positive, default=LEASE_S, metavar="S",
                        help=f"liveliness lease: a participant silent this many seconds (frozen, cut off) is seen "
                        f"gone by the others; give every process of a team the same (default {LEASE_S:g})")


def robot_ids(text: str) -> list[int]:
    """``3``, ``0-7`` or ``0,2,4``."""
    try:
        ids: list[int] = []
        for part in text.split(","):
            first, _, last = part.partition("-")
            span = range(int(first), int(last or first) + 1)
            if not span:
                raise ValueError(part)
            ids += list(span)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--id {text!r}: give a robot index like 3, or ascending ones like 0-7 or 0,2,4") from None
    if len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"--id {text!r} names a robot twice; give each robot once")
    return ids


def run_id(text: str) -> int:
    try:
        value = int(text, 16)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--run {text!r}: give the run id in hex, e.g. 1f2e3d4c") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"--run {text!r}: the run id has at most 8 hex digits")
    return value


def bus_config(args: argparse.Namespace, names: list[str], robots: int | None, admin_space: bool = False) -> BusConfig:
    """The bus of participants ``names`` (of a team of ``robots``) from the role's flags; with
    ``--secure DIR`` mutual TLS and access control (:func:`ringtrack.bus.security.secure_config`)."""
    listen, connect = tuple(args.listen or (LOOPBACK_ANY_PORT,)), tuple(args.connect or ())
    lease_ms = round(args.lease * 1000)
    if args.secure is None:
        return BusConfig(mode=args.mode, listen=listen, connect=connect, admin_space=admin_space, lease_ms=lease_ms)

    return secure_config(args.secure, names, robots, args.mode, listen, connect, admin_space, lease_ms)


def digests(args: argparse.Namespace) -> bool:
    """Whether the world reports to the monitor in digests (lockstep without ``--audit``) its own
    links and the robots' own counts of their robot-to-robot messages, rather than the monitor
    receiving a copy of every measurement, command, request, reply and push."""
    return args.clock == "lockstep" and not args.audit


def finished(role: str, code: int) -> int:
    """Say why a role stops with code 1 (the world vanished without ending the run); pass the code on."""
    if code == 1:
        err.print(f"{role}: the world went away without ending the run (it crashed or was killed); stopping",
                  highlight=False)
    return code
