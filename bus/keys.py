"""Key expressions of one run. Every key lives under ``ringtrack/<run>`` so two runs never meet.

Data keys read ``ringtrack/<run>/<destination>/<source>/<kind>`` with participants named ``world``,
``monitor``, ``fusion`` (the centralized estimator), ``all`` (broadcast) and ``r<i>`` (robot i), so
the monitor learns the link of every message from its key alone. Liveliness tokens live under
``ringtrack/<run>/alive/<name>`` (the process is up), ``ringtrack/<run>/ready/<name>`` (it has seen
everyone it talks to), ``ringtrack/<run>/claim/<name>/<life>-<session>`` (one session's claim on a
name, as its life) and ``ringtrack/<run>/reach/<observed>/<observer>`` (``observer`` sees
``observed`` alive: :mod:`bus.reach`). A joining robot queries ``ringtrack/<run>/life/<name>`` for
its life number (:mod:`bus.lives`).
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property, lru_cache

ROOT = "ringtrack"
WORLD = "world"
MONITOR = "monitor"
FUSION = "fusion"
ROUTER = "router"  # a Zenoh router of a secure team (not a run participant: it has a certificate, no keys)
BROADCAST = "all"

ROBOT_NAME = re.compile(r"^r(0|[1-9][0-9]{0,5})$")


def new_run_id() -> int:
    """A random 32-bit run id in [2^31, 2^32) (always the same size on the wire)."""
    return 2**31 + secrets.randbits(31)


def robot_name(robot: int) -> str:
    return f"r{robot}"


def participants(robots: Iterable[int], centralized: bool, monitor: bool) -> set[str]:
    """The names of a run's participants among ``robots`` (robot indices): the world, those robots,
    the fusion centre when estimation is ``centralized``, and the monitor when one is part of the
    run. Every role waits for the ones it talks to by this one list."""
    names = {WORLD} | {robot_name(robot) for robot in robots}
    return names | ({FUSION} if centralized else set()) | ({MONITOR} if monitor else set())


def robot_index(name: str) -> int | None:
    """``i`` for ``"r<i>"``; ``None`` for any other participant name."""
    match = ROBOT_NAME.match(name)
    return int(match.group(1)) if match else None


@dataclass(frozen=True)
class Route:
    """Where a data message goes, parsed from its key."""

    destination: str
    source: str
    kind: str


@dataclass(frozen=True)
class Keys:
    """The key expressions of run ``run`` (a 32-bit id, shown as 8 hex digits)."""

    run: int

    @cached_property
    def prefix(self) -> str:
        return f"{ROOT}/{self.run:08x}"

    def data(self, destination: str, source: str, kind: str) -> str:
        return f"{self.prefix}/{destination}/{source}/{kind}"

    def inbox(self, name: str) -> str:
        """Everything addressed to participant ``name``."""
        return f"{self.prefix}/{name}/**"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"

    def alive(self, name: str = "*") -> str:
        return f"{self.prefix}/alive/{name}"

    def ready(self, name: str = "*") -> str:
        return f"{self.prefix}/ready/{name}"

    def claim(self, name: str, session: str = "*") -> str:
        """The liveliness key by which Zenoh session ``session`` claims participant name ``name``."""
        return f"{self.prefix}/claim/{name}/{session}"

    def life(self, name: str = "*") -> str:
        """The key a joining process queries for a life number of participant ``name`` (:mod:`bus.lives`)."""
        return f"{self.prefix}/life/{name}"

    def reach(self, observed: str = "*", observer: str = "*") -> str:
        """The liveliness key by which ``observer`` says it sees ``observed``'s ``alive`` token."""
        return f"{self.prefix}/reach/{observed}/{observer}"

    def parse(self, key: str) -> Route | None:
        """The route of a data key of this run, or ``None`` for a key of another shape or run."""
        return _parse(self.prefix, key)


def parse_any(key: str) -> tuple[int, Route] | None:
    """``(run id, route)`` of a data key of any run, or ``None`` for a key of another shape."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT:
        return None
    try:
        run = int(parts[1], 16)
    except ValueError:
        return None
    return run, Route(destination=parts[2], source=parts[3], kind=parts[4])


@lru_cache(maxsize=4096)
def _parse(prefix: str, key: str) -> Route | None:
    """Routes repeat for the whole run (a few keys per participant): parse each key once."""
    parts = key.split("/")
    if len(parts) != 5 or f"{parts[0]}/{parts[1]}" != prefix:
        return None
    return Route(destination=parts[2], source=parts[3], kind=parts[4])
