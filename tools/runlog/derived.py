"""What a run-log step record implies, computed in one place for everyone who draws it: the step's
Cerr and Terr, the ring links that fired, and the 2-sigma ellipse of a belief.

Positions and means in metres, covariances in m^2, Cerr in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ringtrack.world.metrics import target_error, true_cerr

LINK_KINDS = ("request", "reply", "push", "probe")  # how a ring link fired
ELLIPSE_SIGMAS = 2.0  # the ellipses drawn hold a belief's 2-sigma region (86 % of a 2-D Gaussian)


def step_errors(record: dict[str, Any]) -> tuple[float, float]:
    """Cerr of the true positions (degrees, :func:`world.metrics.true_cerr`) and Terr (metres, the
    mean distance from each robot's centre to the true target, :func:`world.metrics.target_error`;
    NaN when no robot named a centre) at the start of a step record's step."""
    positions = np.asarray(record["positions"], dtype=float)
    target = np.asarray(record["target"], dtype=float)
    centres = np.array([(math.nan, math.nan) if centre is None else centre for centre in record["centre"]])
    return float(true_cerr(positions, target)), float(target_error(centres, target))


@dataclass(frozen=True)
class FiredLink:
    """Messages ``sender -> receiver`` (robot ids) of one ``kind`` (:data:`LINK_KINDS`) in a step;
    ``dropped`` names why the fault layer dropped them (drop, outage, range, gone, radio), None
    when they were put on the bus."""

    kind: str
    sender: int
    receiver: int
    messages: int = 1
    dropped: str | None = None


def fired_links(record: dict[str, Any], events: Iterable[dict[str, Any]] = ()) -> list[FiredLink]:
    """The ring links a step record's messages crossed, and the messages of the step the fault layer
    dropped (the ``dropped`` ``events`` of that step; other events are ignored). A request of a robot
    that did not poll that step probes an unreachable neighbour: its kind is "probe". A log written
    before steps held ``links``: each polling robot's requests and their replies, from its trigger."""
    step, trigger = record["step"], record["trigger"]
    logged = record.get("links")
    if logged is None:
        robots = len(trigger)
        logged = [row for robot, mask in enumerate(trigger) if mask
                  for neighbour in ((robot - 1) % robots, (robot + 1) % robots)
                  for row in (("request", robot, neighbour, 1), ("reply", neighbour, robot, 1))]
    links = [FiredLink(_kind(kind, sender, trigger), sender, receiver, messages)
             for kind, sender, receiver, messages in logged]
    for event in events:
        if event.get("event") == "dropped" and event.get("step") == step and event.get("sender") is not None:
            sender, receiver = event["sender"], event["receiver"]
            links.append(FiredLink(_kind(event.get("subject") or "request", sender, trigger), sender, receiver,
                                   1, event.get("reason") or "drop"))
    return links


def _kind(kind: str, sender: int, trigger: list[int | None]) -> str:
    """``kind`` as drawn: a request from a robot that did not poll is a probe."""
    return "probe" if kind == "request" and not trigger[sender] else kind


def covariance_ellipse(mean: Any, covariance: Any, points: int = 48,
                       sigmas: float = ELLIPSE_SIGMAS) -> NDArray[np.float64]:
    """``points`` points (metres, shape (points, 2), counter-clockwise, the first not repeated) on
    the ``sigmas``-sigma ellipse of a Gaussian belief: ``mean`` (x, y) metres and ``covariance``
    packed ``(xx, xy, yy)`` m^2 or as a 2x2 matrix."""
    matrix = np.asarray(covariance, dtype=float)
    if matrix.shape == (3,):
        matrix = np.array([[matrix[0], matrix[1]], [matrix[1], matrix[2]]])
    variances, axes = np.linalg.eigh(matrix)
    radii = sigmas * np.sqrt(np.clip(variances, 0.0, None))
    angles = np.linspace(0.0, 2.0 * np.pi, points, endpoint=False)
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    return np.asarray(mean, dtype=float) + (unit * radii) @ axes.T
