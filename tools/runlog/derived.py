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


def distrust(end: dict[str, Any]) -> str | None:
    """Why a run's results cannot be trusted, from its end record, or None: its books do not balance
    (the monitor's count of some link differs from its senders', every life of each), or two
    processes ran as the same life of one robot (an id collision no fence caught)."""
    reasons = []
    if end.get("consistent") is False:
        reasons.append("its books do not balance (the monitor's counts differ from the senders')")
    if collisions := end.get("notes", {}).get("id_collisions", 0):
        reasons.append(f"two processes ran as one robot ({collisions} id collisions)")
    return "; ".join(reasons) or None


def step_errors(record: dict[str, Any]) -> tuple[float, float]:
    """Cerr of the true positions (degrees, :func:`world.metrics.true_cerr`) and Terr (metres, the
    mean distance from each robot's centre to the true target, :func:`world.metrics.target_error`;
    NaN when no robot named a centre) at the start of a step record's step."""
    positions = np.asarray(record["positions"], dtype=float)
    target = np.asarray(record["target"], dtype=float)
    centres = np.array([(math.nan, math.nan) if centre is None else centre for centre in record["centre"]])
    return float(true_cerr(positions, target)), float(target_error(centres, target))


def team_energy(record: dict[str, Any]) -> float | None:
    """The team's radio energy of the steps before a step record's (joules, transmit and receive,
    :mod:`bus.radio`) by its ``energy_j``, the robots' own counts; None where no robot reported (an
    older log, or a step no command reached)."""
    reported = [sum(energy) for energy in record.get("energy_j") or [] if energy is not None]
    return float(sum(reported)) if reported else None


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


def ellipse_axes(covariance: Any, sigmas: float = ELLIPSE_SIGMAS) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Semi-axes (metres, shape (..., 2), the minor first) of the ``sigmas``-sigma ellipses of
    covariances packed ``(..., 3)`` as ``xx, xy, yy`` (m^2), and the direction of each major axis
    (radians CCW from +x, shape (...))."""
    packed = np.asarray(covariance, dtype=float)
    matrix = np.stack([packed[..., 0], packed[..., 1], packed[..., 1], packed[..., 2]], axis=-1)
    variances, axes = np.linalg.eigh(matrix.reshape(*packed.shape[:-1], 2, 2))
    radii = sigmas * np.sqrt(np.clip(variances, 0.0, None))
    return radii, np.arctan2(axes[..., 1, 1], axes[..., 0, 1])


def covariance_ellipse(mean: Any, covariance: Any, points: int = 48,
                       sigmas: float = ELLIPSE_SIGMAS) -> NDArray[np.float64]:
    """``points`` points (metres, shape (points, 2), counter-clockwise, the first not repeated) on
    the ``sigmas``-sigma ellipse of a Gaussian belief: ``mean`` (x, y) metres and ``covariance``
    packed ``(xx, xy, yy)`` m^2 (:func:`ellipse_axes`)."""
    (minor, major), angle = ellipse_axes(covariance, sigmas)
    turns = np.linspace(0.0, 2.0 * np.pi, points, endpoint=False)
    local = np.stack([major * np.cos(turns), minor * np.sin(turns)], axis=-1)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return np.asarray(mean, dtype=float) + local @ rotation.T
