"""Run-log records as Foxglove messages: a pure translation, no I/O.

:class:`Translator` turns each record of a run log (dicts as :mod:`tools.runlog.log` writes and reads
them), in file order, into samples ``(topic, message, log time)`` on the channels of :data:`TOPICS`,
stamped with the run's simulated time (nanoseconds from the run's start). The MCAP export, the live
WebSocket view and ``spawn --record`` all log what it returns, so they show one and the same thing.

Everything is drawn in the frame ``world`` (x, y in metres, z = 0 on the ground); a robot's frame
``r<i>`` sits at its position, its x axis towards the centre it steers about (the direction it
watches). Per step record: the region, every robot (sphere, label ``r<i>``, grey once it left), its
frame, the true target, every robot's estimate with its 2-sigma covariance ellipse (a flat ellipsoid) (one estimate,
``fusion``, under centralized estimation), the ring links its messages crossed coloured by kind
(:data:`LINK_COLOURS`; red, with a cross at the midpoint, where the fault layer dropped one), and the
step's scalars on ``/metrics`` (JSON: Cerr in degrees, Terr in metres, messages, bytes and the
team's radio energy so far in joules). Every event record (faults on links, robots leaving and
joining) and the end record become Log entries; the end record also gives each robot's final radio
energy on ``/energy`` (joules).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from ringtrack.tools.runlog.derived import FiredLink, ellipse_axes, fired_links, step_errors, team_energy
from ringtrack.world.scenario import Scenario

try:  # the viz extra; without it the commands say what to install (tools.viz.extra) before they get here
    from foxglove import messages as fm
except ImportError:  # pragma: no cover
    pass

FRAME = "world"

# Topic -> the Foxglove schema of its messages ("json": a JSON channel of METRICS_SCHEMA / ENERGY_SCHEMA).
TOPICS: dict[str, str] = {
    "/region": "SceneUpdate",
    "/robots": "SceneUpdate",
    "/tf": "FrameTransforms",
    "/target": "SceneUpdate",
    "/estimates": "SceneUpdate",
    "/links": "SceneUpdate",
    "/metrics": "json",
    "/log": "Log",
    "/energy": "json",
}
PER_STEP = ("/region", "/robots", "/tf", "/target", "/estimates", "/links", "/metrics")  # a message every step

_NUMBER = {"type": ["number", "null"]}
METRICS_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "ringtrack.StepMetrics",
    "properties": {
        "step": {"type": "integer"},
        "time_s": {"type": "number", "description": "simulated seconds"},
        "cerr_deg": {**_NUMBER, "description": "Cerr of the true positions, degrees"},
        "terr_m": {**_NUMBER, "description": "Terr: mean distance of the robots' estimates to the target, metres"},
        "robot_messages": {"type": "integer", "description": "robot-to-robot messages of the step"},
        "robot_bytes": {**_NUMBER, "description": "their payload bytes (null: an engine log, nothing was sent)"},
        "world_messages": {"type": "integer"},
        "estimation_messages": {"type": "integer"},
        "polls": {"type": "integer", "description": "robots that polled their neighbours this step"},
        "robot_messages_total": {"type": "integer"},
        "polls_total": {"type": "integer"},
        "live_robots": {"type": "integer"},
        "energy_j": {**_NUMBER, "description": "the team's radio energy so far, joules (null: not reported)"},
    },
}
ENERGY_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "ringtrack.RadioEnergy",
    "properties": {
        "transmit_j": {"type": "number"}, "receive_j": {"type": "number"}, "total_j": {"type": "number"},
        "robots": {"type": "object", "description": "robot name -> [transmit, receive] joules"},
    },
}

Rgba = tuple[float, float, float, float]
# matplotlib's tab10, the colours of `ringtrack plot` (robot i takes colour i mod 10)
ROBOT_COLOURS: tuple[Rgba, ...] = tuple(
    (int(code[0:2], 16) / 255, int(code[2:4], 16) / 255, int(code[4:6], 16) / 255, 1.0)
    for code in ("1f77b4", "ff7f0e", "2ca02c", "d62728", "9467bd", "8c564b", "e377c2", "7f7f7f", "bcbd22", "17becf"))
LINK_COLOURS: dict[str, Rgba] = {"request": (0.12, 0.47, 0.71, 1.0), "reply": (0.17, 0.63, 0.17, 1.0),
                                 "push": (1.0, 0.5, 0.05, 1.0), "probe": (0.58, 0.4, 0.74, 1.0)}
DROPPED: Rgba = (0.9, 0.0, 0.0, 1.0)
GONE: Rgba = (0.6, 0.6, 0.6, 0.6)
BLACK: Rgba = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Sample:
    """One message for one topic: a Foxglove message object (a dict on JSON topics) and its log
    time, nanoseconds of simulated time from the run's start."""

    topic: str
    message: Any
    log_time_ns: int


def nanoseconds(seconds: float) -> int:
    """Simulated seconds as integer nanoseconds (the log times of MCAP and of the live view)."""
    return round(seconds * 1e9)


def stamp(seconds: float) -> fm.Timestamp:
    whole = math.floor(seconds)
    return fm.Timestamp(sec=int(whole), nsec=min(999_999_999, round((seconds - whole) * 1e9)))


@lru_cache(maxsize=64)
def _colour(rgba: Rgba) -> fm.Color:
    """The Foxglove colour of ``rgba`` (one object per colour, shared by every message)."""
    return fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _point(xy: Iterable[float], z: float = 0.0) -> fm.Point3:
    x, y = xy
    return fm.Point3(x=float(x), y=float(y), z=z)


def _pose(xy: Iterable[float], yaw: float = 0.0, z: float = 0.0) -> fm.Pose:
    x, y = xy
    return fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=z),
                   orientation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))


class Translator:
    """Foxglove samples of a run's records, fed in file order (:meth:`translate`). It keeps what the
    next records need: running totals, the dropped messages of steps not yet recorded, the latest
    step's time. Sizes of markers follow the region's extent (metres)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.dt = scenario.control.dt
        vertices = scenario.region.vertices
        self.outline = [(float(x), float(y)) for x, y in vertices]
        extent = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
        self.marker = max(extent, 1e-3) * 0.025  # metres: a robot's sphere
        self.robot_size = fm.Vector3(x=self.marker, y=self.marker, z=self.marker)
        self.target_size = fm.Vector3(x=self.marker * 1.2, y=self.marker * 1.2, z=self.marker * 1.2)
        self.estimate_size = fm.Vector3(x=self.marker * 0.5, y=self.marker * 0.5, z=self.marker * 0.5)
        self.outline_line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineLoop, pose=_pose((0.0, 0.0)),
                                             thickness=2.0, scale_invariant=True,
                                             points=[_point(vertex) for vertex in self.outline], color=_colour(BLACK))
        self.centralized = scenario.estimation.mode == "centralized"
        self.known = scenario.estimation.mode == "known"
        self.dropped: dict[int, list[dict[str, Any]]] = defaultdict(list)  # step -> its dropped events so far
        self.time = 0.0  # of the latest step record, simulated seconds
        self.robot_messages_total = 0
        self.polls_total = 0

    def translate(self, record: dict[str, Any]) -> list[Sample]:
        """The samples of one record: a step's scene, frames and metrics, an event's or the end's Log
        entry (and the end's energy); none for a header or another type."""
        kind = record.get("type")
        if kind == "step":
            return self._step(record)
        if kind == "event":
            return self._event(record)
        if kind == "end":
            return self._end(record)
        return []

    # ------------------------------------------------------------------ steps
    def _step(self, record: dict[str, Any]) -> list[Sample]:
        seconds = float(record["time"])
        self.time = seconds
        when, ns = stamp(seconds), nanoseconds(seconds)
        links = fired_links(record, self.dropped.pop(record["step"], ()))
        for stale in [step for step in self.dropped if step < record["step"]]:
            del self.dropped[stale]  # dropped messages of steps already drawn: they are in /log
        scenes = {
            "/region": [self._region(when)],
            "/robots": [self._robot(when, record, robot) for robot in range(len(record["positions"]))],
            "/target": [self._target(when, record)],
            "/estimates": self._estimates(when, record),
            "/links": [self._link(when, record, link, index) for index, link in enumerate(links)],
        }
        samples = [Sample(topic, self._update(when, entities, replace_all=topic != "/region"), ns)
                   for topic, entities in scenes.items()]
        samples.append(Sample("/tf", self._frames(when, record), ns))
        samples.append(Sample("/metrics", self._metrics(record), ns))
        return samples

    def _update(self, when: fm.Timestamp, entities: list[fm.SceneEntity], replace_all: bool) -> fm.SceneUpdate:
        """A scene update that first clears the topic's entities of the previous step (robots that
        left, links that fired then), then draws these."""
        deletions = [fm.SceneEntityDeletion(timestamp=when, type=fm.SceneEntityDeletionType.All)] if replace_all else []
        return fm.SceneUpdate(deletions=deletions, entities=entities)

    def _entity(self, when: fm.Timestamp, name: str, **primitives: Any) -> fm.SceneEntity:
        metadata = [fm.KeyValuePair(key=key, value=str(value)) for key, value in primitives.pop("metadata", {}).items()]
        return fm.SceneEntity(timestamp=when, frame_id=FRAME, id=name, frame_locked=False, metadata=metadata,
                              **primitives)

    def _region(self, when: fm.Timestamp) -> fm.SceneEntity:
        return self._entity(when, "region", lines=[self.outline_line])

    def _yaw(self, record: dict[str, Any], robot: int) -> float:
        """Radians CCW from +x: from the robot towards the centre it steers about (or the target)."""
        x, y = record["positions"][robot]
        cx, cy = record["centre"][robot] or record["target"]
        return math.atan2(cy - y, cx - x)

    def _robot(self, when: fm.Timestamp, record: dict[str, Any], robot: int) -> fm.SceneEntity:
        position = record["positions"][robot]
        alive = robot in record["live"]
        colour = ROBOT_COLOURS[robot % len(ROBOT_COLOURS)] if alive else GONE
        sphere = fm.SpherePrimitive(pose=_pose(position), size=self.robot_size, color=_colour(colour))
        arrow = fm.ArrowPrimitive(pose=_pose(position, self._yaw(record, robot)), shaft_length=self.marker,
                                  shaft_diameter=self.marker / 5, head_length=self.marker / 2,
                                  head_diameter=self.marker / 2.5, color=_colour(colour))
        label = fm.TextPrimitive(pose=_pose(position, z=self.marker), billboard=True, font_size=14.0,
                                 scale_invariant=True, color=_colour(colour if alive else GONE),
                                 text=f"r{robot}" if alive else f"r{robot} (gone)")
        trigger = record["trigger"][robot]
        return self._entity(when, f"r{robot}", spheres=[sphere], arrows=[arrow], texts=[label],
                            metadata={"robot": robot, "live": alive, "trigger": trigger})

    def _frames(self, when: fm.Timestamp, record: dict[str, Any]) -> fm.FrameTransforms:
        transforms = []
        for robot, (x, y) in enumerate(record["positions"]):
            yaw = self._yaw(record, robot)
            transforms.append(fm.FrameTransform(
                timestamp=when, parent_frame_id=FRAME, child_frame_id=f"r{robot}",
                translation=fm.Vector3(x=float(x), y=float(y), z=0.0),
                rotation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))))
        return fm.FrameTransforms(transforms=transforms)

    def _target(self, when: fm.Timestamp, record: dict[str, Any]) -> fm.SceneEntity:
        target = record["target"]
        sphere = fm.SpherePrimitive(pose=_pose(target), size=self.target_size, color=_colour(BLACK))
        label = fm.TextPrimitive(pose=_pose(target, z=self.marker), billboard=True, font_size=14.0,
                                 scale_invariant=True, color=_colour(BLACK), text="target")
        return self._entity(when, "target", spheres=[sphere], texts=[label])

    def _estimates(self, when: fm.Timestamp, record: dict[str, Any]) -> list[fm.SceneEntity]:
        """Each robot's estimate (a small sphere) and its 2-sigma ellipse (a flat translucent
        ellipsoid, :func:`tools.runlog.derived.ellipse_axes`); under centralized estimation every
        robot steers by the fusion centre's, drawn once as ``fusion``; none where the robots know the
        target."""
        if self.known:
            return []
        covariances = record.get("covariance") or [None] * len(record["centre"])
        beliefs = [(f"estimate/r{robot}", centre, covariances[robot], ROBOT_COLOURS[robot % len(ROBOT_COLOURS)])
                   for robot, centre in enumerate(record["centre"]) if centre is not None]
        if self.centralized and beliefs:
            beliefs = [("estimate/fusion", beliefs[0][1], beliefs[0][2], (0.85, 0.65, 0.13, 1.0))]
        known = [covariance for _, _, covariance, _ in beliefs if covariance is not None]
        radii, angles = ellipse_axes(known) if known else (None, None)
        entities, index = [], 0
        for name, mean, covariance, rgba in beliefs:
            spheres = [fm.SpherePrimitive(pose=_pose(mean), size=self.estimate_size, color=_colour(rgba))]
            metadata: dict[str, Any] = {}
            if covariance is not None and radii is not None and angles is not None:
                (minor, major), angle = radii[index], float(angles[index])
                index += 1
                size = fm.Vector3(x=2 * float(major), y=2 * float(minor), z=self.marker * 0.05)
                spheres.append(fm.SpherePrimitive(pose=_pose(mean, angle), size=size,
                                                  color=_colour((rgba[0], rgba[1], rgba[2], 0.25))))
                metadata["covariance_m2"] = list(covariance)
            entities.append(self._entity(when, name, spheres=spheres, metadata=metadata))
        return entities

    def _link(self, when: fm.Timestamp, record: dict[str, Any], link: FiredLink, index: int) -> fm.SceneEntity:
        """A message crossing a ring link, a line from sender to receiver slightly off the straight
        link (so a request and its reply lie side by side); a dropped one red with a cross halfway."""
        start, end = record["positions"][link.sender], record["positions"][link.receiver]
        dx, dy = end[0] - start[0], end[1] - start[1]
        length = math.hypot(dx, dy) or 1.0
        shift = self.marker * 0.3
        nx, ny = -dy / length * shift, dx / length * shift  # to the left of the direction of travel
        a, b = (start[0] + nx, start[1] + ny), (end[0] + nx, end[1] + ny)
        rgba = DROPPED if link.dropped else LINK_COLOURS[link.kind]
        lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, pose=_pose((0.0, 0.0)), thickness=3.0,
                                  scale_invariant=True, points=[_point(a, 0.01), _point(b, 0.01)],
                                  color=_colour(rgba))]
        if link.dropped:
            mx, my, c = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2, self.marker * 0.6
            cross = [_point((mx - c, my - c), 0.01), _point((mx + c, my + c), 0.01),
                     _point((mx - c, my + c), 0.01), _point((mx + c, my - c), 0.01)]
            lines.append(fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, pose=_pose((0.0, 0.0)),
                                          thickness=3.0, scale_invariant=True, points=cross, color=_colour(DROPPED)))
        state = f"dropped ({link.dropped})" if link.dropped else "delivered"
        return self._entity(when, f"{link.kind}/r{link.sender}-r{link.receiver}/{index}", lines=lines,
                            lifetime=fm.Duration.from_secs(self.dt),
                            metadata={"kind": link.kind, "sender": link.sender, "receiver": link.receiver,
                                      "messages": link.messages, "state": state})

    def skip(self, record: dict[str, Any]) -> None:
        """Account for a step record that is not drawn (a live view shows only the latest step it
        can keep up with): its messages and polls still count in the running totals."""
        self._account(record)
        self.dropped.pop(record["step"], None)

    def _account(self, record: dict[str, Any]) -> tuple[int, int]:
        """Add a step's robot-to-robot messages and polls to the running totals; returns them."""
        robot_messages = record["traffic"].get("robot", [0, None])[0]
        polls = sum(1 for trigger in record["trigger"] if trigger)
        self.robot_messages_total += robot_messages
        self.polls_total += polls
        return robot_messages, polls

    def _metrics(self, record: dict[str, Any]) -> dict[str, Any]:
        cerr, terr = step_errors(record)
        robot_bytes = record["traffic"].get("robot", [0, None])[1]
        robot_messages, polls = self._account(record)
        return {
            "step": record["step"], "time_s": record["time"],
            "cerr_deg": None if math.isnan(cerr) else cerr, "terr_m": None if math.isnan(terr) else terr,
            "robot_messages": robot_messages, "robot_bytes": robot_bytes,
            "world_messages": record["traffic"].get("world", [0, None])[0],
            "estimation_messages": record["traffic"].get("estimation", [0, None])[0],
            "polls": polls, "robot_messages_total": self.robot_messages_total, "polls_total": self.polls_total,
            "live_robots": len(record["live"]),
            "energy_j": team_energy(record),
        }

    # ------------------------------------------------------------------ events and the end
    def _event(self, record: dict[str, Any]) -> list[Sample]:
        """A Log entry at the start of the event's step (a warning for a drop, a robot that left)."""
        step = int(record.get("step") or 0)
        seconds = max(step - 1, 0) * self.dt
        what = record["event"]
        if what == "dropped" and record.get("sender") is not None:
            self.dropped[step].append(record)
        if what == "nemesis":  # a fault a nemesis carried out (tools.team.nemesis)
            text, name = f"nemesis: {record.get('subject')}", "nemesis"
        elif record.get("robot") is not None:
            said = {"left": "left the ring", "joined": "joined", "life": f"joined as {record.get('subject')}"}
            text = f"{record['robot']} {said.get(what, what)}"
            name = record["robot"]
        else:
            text = f"{what} {record.get('subject') or 'message'} r{record.get('sender')} -> r{record.get('receiver')}"
            text += f" ({record['reason']})" if record.get("reason") else ""
            text += f" by {record['delay_s']:g} s" if record.get("delay_s") else ""
            name = f"r{record.get('sender')}"
        level = fm.LogLevel.Warning if what in ("dropped", "left", "nemesis") else fm.LogLevel.Info
        entry = fm.Log(timestamp=stamp(seconds), level=level, message=f"step {step}: {text}", name=name,
                       file="", line=0)
        return [Sample("/log", entry, nanoseconds(seconds))]

    def _end(self, record: dict[str, Any]) -> list[Sample]:
        ns = nanoseconds(self.time)
        level = fm.LogLevel.Info if record.get("consistent") is not False else fm.LogLevel.Warning
        text = f"run ended after {record['steps']} steps: {record['reason']}"
        if record.get("consistent") is False:
            text += "; the monitor's totals differ from what the senders counted"
        energy = record.get("energy_j") or {}
        transmit = sum(pair[0] for pair in energy.values())
        receive = sum(pair[1] for pair in energy.values())
        return [Sample("/log", fm.Log(timestamp=stamp(self.time), level=level, message=text, name="monitor",
                                      file="", line=0), ns),
                Sample("/energy", {"transmit_j": transmit, "receive_j": receive, "total_j": transmit + receive,
                                   "robots": {name: list(pair) for name, pair in energy.items()}}, ns)]


def translate_all(scenario: Scenario, records: Iterable[dict[str, Any]]) -> list[Sample]:
    """The samples of a whole run's records, in file order."""
    translator = Translator(scenario)
    return [sample for record in records for sample in translator.translate(record)]
