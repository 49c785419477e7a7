"""``ringtrack certs DIR --robots N``: the team folder of a secure team (``--secure DIR``): an
authority and a key and certificate per participant; ``ringtrack certs DIR --show`` lists it."""

from __future__ import annotations

import argparse
import datetime
import re
from pathlib import Path

from rich.table import Table

from ringtrack.bus.security import create_team, list_team, load_team
from ringtrack.tools.cli.options import at_least
from ringtrack.tools.output.console import UsageError, out, show

HOST = re.compile(r"^([0-9A-Fa-f:.]+|[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}"
                  r"[A-Za-z0-9])?)*)$")


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        "certs",
        help="make the certificates of a secure team (for --secure DIR), or --show them",
        description="Create DIR with an authority (ca.pem, ca.key) and a key and certificate per participant "
        "(world, monitor, fusion, router, r0..r{N-1}), each certificate naming its participant. Copy DIR to "
        "every host of the team (ca.key may stay behind: only this command needs it).",
    )
    parser.add_argument("directory", type=Path, metavar="DIR", help="team folder to create (or to --show)")
    parser.add_argument("--robots", type=at_least(1), metavar="N", help="team size: robots r0..r{N-1}")
    parser.add_argument("--hosts", nargs="+", default=[], metavar="HOST",
                        help="addresses or names participants listen on besides loopback, e.g. 10.0.0.1 10.0.0.2")
    parser.add_argument("--days", type=at_least(1), default=365, help="validity in days (default 365)")
    parser.add_argument("--force", action="store_true", help="replace the certificates of an existing DIR")
    parser.add_argument("--show", action="store_true", help="list the certificates in DIR and when each expires")
    parser.set_defaults(handler=run_certs)


def hosts_from(values: list[str]) -> tuple[str, ...]:
    """``--hosts`` values, each a list separated by commas or spaces, checked."""
    hosts = tuple(host for value in values for host in value.replace(",", " ").split())
    for host in hosts:
        if not HOST.match(host):
            raise UsageError(f"--hosts {host!r}: give an IP address or a DNS name, e.g. 10.0.0.1 or robot-b.local")
    return hosts


def run_certs(args: argparse.Namespace) -> int:
    if args.show:
        show(team_table(args.directory))
        return 0
    if args.robots is None:
        raise UsageError("certs: give the team size with --robots N (or --show to list DIR)")
    names = create_team(args.directory, args.robots, hosts_from(args.hosts), args.force, args.days)
    out.print(f"{args.directory}: authority and {len(names)} certificates ({', '.join(names[:6])}"
              f"{', ...' if len(names) > 6 else ''}); copy the folder to every host and give --secure "
              f"{args.directory}", highlight=False, soft_wrap=True)
    return 0


def team_table(directory: Path) -> Table:
    team = load_team(directory, flag="certs")
    now = datetime.datetime.now(datetime.UTC)
    entries = list_team(directory)
    hosts = next((entry.hosts for entry in entries if entry.hosts), ())
    table = Table(title=f"{directory.name}: a team of {team.robots} robots",
                  caption=f"certificates valid for {', '.join(hosts)}")
    for column in ("file", "common name", "expires (UTC)", "key file mode"):
        table.add_column(column)
    for entry in entries:
        left = (entry.expires - now).days
        expiry = f"{entry.expires:%Y-%m-%d %H:%M}" + (" EXPIRED" if entry.expires <= now else f" ({left} days)")
        key = "-" if entry.key_mode is None else f"{entry.key_mode:o}" + ("" if entry.key_mode == 0o600 else " (!)")
        table.add_row(entry.file, entry.common_name, expiry, key)
    return table
