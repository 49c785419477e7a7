"""``ringtrack router``: a Zenoh router for teams spread over several hosts."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from pathlib import Path

from ringtrack.bus.config import announce_endpoints, listening_locators, open_session
from ringtrack.bus.keys import ROUTER
from ringtrack.tools.cli.role_flags import SECURE_HELP, bus_config, lease_flag
from ringtrack.tools.output.console import err


def register(commands: argparse._SubParsersAction) -> None:
    router = commands.add_parser(
        "router",
        help="run a Zenoh router for teams spread over several hosts",
        description="A Zenoh router (no zenohd needed): hosts connect to it with --connect "
        "tcp/<router-ip>:<port> (as --mode client, or as peers). It serves every run; stop it with Ctrl-C.",
    )
    router.add_argument("--listen", action="append", metavar="ENDPOINT", required=True,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447; repeatable")
    router.add_argument("--connect", action="append", metavar="ENDPOINT", help="another router; repeatable")
    router.add_argument("--announce", type=Path, metavar="PATH",
                        help="write the endpoints the router listens on to PATH (JSON; useful with port 0)")
    router.add_argument("--secure", type=Path, metavar="DIR", help=SECURE_HELP)
    lease_flag(router)
    router.add_argument("--exit-with-parent", action="store_true", help=argparse.SUPPRESS)
    router.set_defaults(handler=run_router_role)


def run_router_role(args: argparse.Namespace) -> int:
    """A Zenoh router until SIGINT, SIGTERM or (``--exit-with-parent``) the end of standard input."""
    args.mode = "router"
    config = bus_config(args, [ROUTER], None, admin_space=True)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    if args.exit_with_parent:
        def wait_for_parent() -> None:
            while os.read(sys.stdin.fileno(), 4096):
                pass
            stop.set()

        threading.Thread(target=wait_for_parent, daemon=True).start()
    with open_session(config, ROUTER) as session:
        if args.announce is not None:
            announce_endpoints(session, args.announce)
        err.print(f"router listening on {', '.join(listening_locators(session))}; Ctrl-C to stop", highlight=False)
        stop.wait()
    return 0
