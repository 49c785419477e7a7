"""``ringtrack export LOG --csv DIR``: a run log as tables any analysis tool loads.

``DIR/steps.csv`` is long: one row per step and robot (step, simulated time, robot, position,
angle about the centre it steers by, gV - theta, trigger mask and reasons, memory ages, robot-to-robot
messages and bytes sent and received). ``DIR/links.csv`` has one row per (kind, source,
destination) link of the end record: messages and bytes the monitor saw, and the sender's own
counts. Empty cells: not known (a robot that sent no command that step; bytes of an engine log).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

from ringtrack.agents.laws import reason_text
from ringtrack.bus.counting import summed
from ringtrack.tools.runlog.log import RunLog
from ringtrack.world.geometry import angle_of

STEP_COLUMNS = ["step", "time_s", "robot", "live", "x_m", "y_m", "angle_deg", "offset_deg", "trigger", "reasons",
                "age_pred_steps", "age_succ_steps", "centre_x_m", "centre_y_m", "target_x_m", "target_y_m",
                "sent_messages", "sent_bytes", "received_messages", "received_bytes"]
LINK_COLUMNS = ["kind", "source", "destination", "messages_seen", "bytes_seen", "messages_sent", "bytes_sent"]


def step_rows(log: RunLog) -> Iterator[dict]:
    """One row per step and robot (angles in degrees, CCW, about the robot's own centre)."""
    for record in log.steps:
        live = set(record["live"])
        for robot, (x, y) in enumerate(record["positions"]):
            centre, offset, ages = record["centre"][robot], record["offset"][robot], record["ages"][robot]
            trigger = record["trigger"][robot]
            pred, succ = ages or (None, None)
            centre_x, centre_y = centre or (None, None)
            angle = None if centre is None else math.degrees(float(angle_of((x, y), centre))) % 360.0
            yield {
                "step": record["step"], "time_s": record["time"], "robot": robot, "live": int(robot in live),
                "x_m": x, "y_m": y, "angle_deg": angle,
                "offset_deg": None if offset is None else math.degrees(offset),
                "trigger": trigger, "reasons": None if trigger is None else reason_text(trigger),
                "age_pred_steps": pred, "age_succ_steps": succ, "centre_x_m": centre_x, "centre_y_m": centre_y,
                "target_x_m": record["target"][0], "target_y_m": record["target"][1],
                "sent_messages": record["sent_messages"][robot],
                "sent_bytes": None if record["sent_bytes"] is None else record["sent_bytes"][robot],
                "received_messages": record["received_messages"][robot],
                "received_bytes": None if record["received_bytes"] is None else record["received_bytes"][robot],
            }


def link_rows(log: RunLog) -> Iterator[dict]:
    """One row per (kind, source, destination) of the end record: seen by the monitor, and as sent."""
    end = log.end or {}
    counted = end.get("traffic", [])
    seen = summed(counted, lambda row: tuple(row[:3]))
    bytes_known = {tuple(row[:3]) for row in counted if row[4] is not None}
    sent = summed((row for rows in end.get("senders", {}).values() for row in rows), lambda row: tuple(row[:3]))
    for link in sorted(seen.keys() | sent.keys()):
        mine, theirs = seen.get(link), sent.get(link)
        yield {
            "kind": link[0], "source": link[1], "destination": link[2],
            "messages_seen": None if mine is None else mine["messages"],
            "bytes_seen": mine["bytes"] if mine is not None and link in bytes_known else None,
            "messages_sent": None if theirs is None else theirs["messages"],
            "bytes_sent": None if theirs is None else theirs["bytes"],
        }
