"""A nemesis: process faults scheduled against a live team, in wall seconds after its first step.

A plan is a short string of faults separated by commas (or a TOML file whose ``[nemesis]`` table
holds ``faults = [...]``)::

    kill r3@5s, restart r3@8s, pause r1@10s:3s, kill monitor@15s

``kill NAME@T`` sends SIGKILL to a robot (``r<i>``), the monitor or the world; ``restart r<i>@T``
starts a new process for robot i (it joins as the id's next life, :mod:`bus.lives`); ``restart
monitor@T``, after a ``kill monitor``, starts a monitor that resumes the run's log and books (the
world holds the run for it meanwhile: :func:`monitor_grace_s`, :mod:`world.backlog`); ``pause
NAME@T:D`` freezes a process with SIGSTOP for D seconds, then wakes it with SIGCONT; ``partition
r<a>-r<b>@T:D`` cuts the link between two robots for D seconds (their fault layers drop every
message between them as an ``outage``; :data:`bus.faults.PARTITION_FILE`). Every fault
carried out is written, with when, at which step of the run and to which pid, to ``nemesis.jsonl``
in the run folder, to the run's summary and, once the run is over, to its log as ``nemesis``
events. :func:`random_plan` draws seeded plans for ``ringtrack experiment nemesis``.
"""

from __future__ import annotations

import dataclasses
import json
import random
import re
import signal
import time
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import msgspec

from ringtrack.bus.faults import PARTITION_FILE
from ringtrack.bus.keys import MONITOR, WORLD, robot_index, robot_name
from ringtrack.tools.output.console import UsageError

Action = Literal["kill", "restart", "pause", "partition"]
FAULT = re.compile(r"^(?P<action>[a-z]+)\s+(?P<target>[a-z0-9]+(?:-r[0-9]+)?)\s*@\s*(?P<at>\d+(?:\.\d+)?)s"
                   r"(?::(?P<for>\d+(?:\.\d+)?)s)?$")
EXAMPLE = "kill r3@5s, restart r3@8s, pause r1@10s:3s, partition r0-r2@12s:4s, kill monitor@15s"
LASTING = ("pause", "partition")  # the faults that last a given time


class Fault(msgspec.Struct, frozen=True):
    """One scheduled fault: ``action`` on participant ``target`` (a partition: the link ``r<a>-r<b>``)
    at ``at_s`` wall seconds after the first step, lasting ``for_s`` seconds (a pause or a
    partition)."""

    action: Action
    target: str
    at_s: float
    for_s: float | None = None

    def __str__(self) -> str:
        lasting = f":{self.for_s:g}s" if self.for_s is not None else ""
        return f"{self.action} {self.target}@{self.at_s:g}s{lasting}"


def parse_fault(text: str, robots: int) -> Fault:
    """One fault of a plan; a :class:`UsageError` naming it and the fix when it is not one."""
    match = FAULT.match(text.strip())
    if match is None:
        raise UsageError(f"--nemesis {text.strip()!r}: write a fault like 'kill r3@5s' or 'pause r1@10s:3s' "
                         f"(e.g. {EXAMPLE})")
    action, target = match["action"], match["target"]
    if action not in ("kill", "restart", *LASTING):
        raise UsageError(f"--nemesis {text.strip()!r}: unknown action {action!r}; use kill, restart, pause or "
                         "partition")
    if action == "partition":
        return _partition(text.strip(), target, match, robots)
    robot = robot_index(target)
    if robot is None and target not in (MONITOR, WORLD):
        raise UsageError(f"--nemesis {text.strip()!r}: {target!r} is no participant; name r0..r{robots - 1}, "
                         "monitor or world")
    if robot is not None and robot >= robots:
        raise UsageError(f"--nemesis {text.strip()!r}: the team has robots r0..r{robots - 1}")
    if action == "restart" and target == WORLD:
        raise UsageError(f"--nemesis {text.strip()!r}: only a robot or the monitor can be restarted")
    lasting = float(match["for"]) if match["for"] is not None else None
    if (action == "pause") != (lasting is not None):
        raise UsageError(f"--nemesis {text.strip()!r}: a pause needs its length (pause r1@10s:3s), and only a pause "
                         "or a partition has one")
    return Fault(action, target, float(match["at"]), lasting)  # type: ignore[arg-type]


def _partition(text: str, target: str, match: re.Match[str], robots: int) -> Fault:
    """A ``partition r<a>-r<b>@T:D`` fault (the link between two robots cut for D seconds)."""
    ends = [robot_index(name) for name in target.split("-")]
    if len(ends) != 2 or None in ends or ends[0] == ends[1]:
        raise UsageError(f"--nemesis {text!r}: a partition cuts the link of two robots: partition r0-r2@12s:4s")
    if any(robot is not None and robot >= robots for robot in ends):
        raise UsageError(f"--nemesis {text!r}: the team has robots r0..r{robots - 1}")
    if match["for"] is None:
        raise UsageError(f"--nemesis {text!r}: a partition needs its length (partition r0-r2@12s:4s)")
    return Fault("partition", target, float(match["at"]), float(match["for"]))



def partition_ends(fault: Fault) -> tuple[int, int]:
    """The two robots of a partition fault's link."""
    first, second = (robot_index(name) or 0 for name in fault.target.split("-"))
    return first, second


def parse_plan(plan: str, robots: int) -> list[Fault]:
    """The faults of a plan string, or of a TOML file's ``[nemesis] faults`` when ``plan`` names one,
    in time order."""
    path = Path(plan)
    if plan.endswith(".toml"):
        try:
            table = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as error:
            raise UsageError(f"--nemesis {plan}: {error}; give a TOML file with [nemesis] faults = [...]") from None
        faults = table.get("nemesis", {}).get("faults")
        if not isinstance(faults, list) or not all(isinstance(fault, str) for fault in faults):
            raise UsageError(f"--nemesis {plan}: [nemesis] faults must be a list of strings like \"kill r3@5s\"")
        texts = faults
    else:
        texts = [text for text in plan.split(",") if text.strip()]
    if not texts:
        raise UsageError(f"--nemesis {plan!r}: no fault in it; e.g. {EXAMPLE}")
    faults = sorted((parse_fault(text, robots) for text in texts), key=lambda fault: fault.at_s)
    killed = False
    for fault in faults:
        if fault.target == MONITOR and fault.action == "restart" and not killed:
            raise UsageError(f"--nemesis {str(fault)!r}: a monitor is restarted after it was killed: "
                             f"kill monitor@{max(fault.at_s - 2, 0):g}s, {fault}")
        if fault.target == MONITOR:
            killed = fault.action == "kill"
    return faults


MONITOR_RETURN_S = 30.0  # s: how long a restarted monitor may take to come up and resume, beyond its plan


def monitor_grace_s(faults: list[Fault]) -> float | None:
    """How long the world must hold the run for a monitor the plan kills and then restarts (the
    longest wait from a ``kill monitor`` to the ``restart monitor`` after it, plus
    ``MONITOR_RETURN_S``), None when the plan restarts no monitor."""
    waits, killed_at = [], None
    for fault in faults:
        if fault.target == MONITOR and fault.action == "kill":
            killed_at = fault.at_s
        elif fault.target == MONITOR and fault.action == "restart" and killed_at is not None:
            waits.append(fault.at_s - killed_at)
    return max(waits) + MONITOR_RETURN_S if waits else None


def split_brain(name: str, at_s: float, lease_s: float) -> list[Fault]:
    """Freeze ``name`` past the lease, start a new life of it once the team has seen it gone, then
    wake the old one: two processes would act as one robot but for the fence (:mod:`bus.lives`)."""
    return [Fault("pause", name, at_s, round(3.0 * lease_s, 1)), Fault("restart", name, round(at_s + 1.5 * lease_s, 1))]


def random_plan(seed: int, robots: int, span_s: float, faults: int = 3, lease_s: float = 2.0) -> list[Fault]:
    """A seeded random plan of ``faults`` robot faults, each begun and over (the robot restarted,
    woken, the link healed) within the first ``span_s`` seconds: kills followed by a restart of the
    same robot, short pauses (below a ``lease_s`` liveliness lease), long ones (past it), split
    brains (:func:`split_brain`) and partitions of the robot's link to its counter-clockwise
    neighbour; each robot takes at most one of them."""
    rng = random.Random(seed)
    plan: list[Fault] = []
    for robot in rng.sample(range(robots), min(faults, robots)):
        name = robot_name(robot)
        kind = rng.choice(("kill", "pause", "pause", "split", "partition"))
        if kind == "kill":
            delay = rng.uniform(0.5, 3.0)
            at = round(rng.uniform(0.0, max(0.0, span_s - delay)), 1)
            plan += [Fault("kill", name, at), Fault("restart", name, round(at + delay, 1))]
        elif kind == "split":
            plan += split_brain(name, round(rng.uniform(0.0, max(0.0, span_s - 3.0 * lease_s)), 1), lease_s)
        else:
            long = kind == "partition" or rng.random() < 0.5
            length = round(rng.uniform(1.25, 2.0) * lease_s if long else rng.uniform(0.1, 0.5) * lease_s, 1)
            at = round(rng.uniform(0.0, max(0.0, span_s - length)), 1)
            target = f"{name}-{robot_name((robot + 1) % robots)}" if kind == "partition" else name
            plan.append(Fault(kind, target, at, length))  # type: ignore[arg-type]
    return sorted(plan, key=lambda fault: fault.at_s)


@dataclasses.dataclass
class Struck:
    """A fault carried out: when (seconds after the first step, and the last step logged by then),
    what, on which process, and the wall-clock time (seconds since the epoch)."""

    at_s: float
    step: int
    fault: str
    pid: int | None
    wall: float


class Nemesis:
    """Carries a plan out against a team: :meth:`tick` (called as the supervisor polls) does every
    fault that fell due. ``find(name)`` gives the newest process of a participant (None: none
    running), ``signal(process, number)`` signals it, ``restart(name)`` starts a new one and
    ``spare(process)`` tells the supervisor that it ends by the nemesis's hand, not by failing."""

    def __init__(self, faults: list[Fault], folder: Path, find: Callable[[str], object | None],
                 send: Callable[[object, int], int | None], restart: Callable[[str], int],
                 spare: Callable[[object], None], step: Callable[[], int]) -> None:
        self.cuts: set[tuple[int, int]] = set()  # the robot links a partition cuts now
        pending: list[tuple[float, str, Fault]] = []
        for fault in faults:
            pending.append((fault.at_s, "start", fault))
            if fault.for_s is not None:
                pending.append((fault.at_s + fault.for_s, "end", fault))
        self.pending = sorted(pending, key=lambda entry: entry[0])
        self.path = folder / "nemesis.jsonl"
        self.find, self.send, self.restart, self.spare, self.step = find, send, restart, spare, step
        self.struck: list[Struck] = []
        self.paused: dict[Fault, object] = {}

    def tick(self, since_first_step_s: float | None, over: bool = False) -> None:
        """Carry out every fault due ``since_first_step_s`` seconds after the first step (None: the
        run has not stepped yet); once the run is ``over``, no fault more, and every paused process
        is woken (it must end with its team)."""
        if over:
            ending = [fault for _, phase, fault in self.pending if phase == "end" and fault.action == "partition"
                      and partition_ends(fault) in self.cuts]
            self.pending.clear()
            for fault, process in list(self.paused.items()):  # woken late to end with its team: no failure
                self.spare(process)
                self._carry_out(fault, "end", since_first_step_s or 0.0)
            for fault in ending:
                self._carry_out(fault, "end", since_first_step_s or 0.0)
            return
        while self.pending and since_first_step_s is not None and self.pending[0][0] <= since_first_step_s:
            _, phase, fault = self.pending.pop(0)
            self._carry_out(fault, phase, since_first_step_s)

    def _carry_out(self, fault: Fault, phase: str, now_s: float) -> None:
        pid: int | None = None
        if fault.action == "restart":
            pid = self.restart(fault.target)
        elif fault.action == "partition":
            (self.cuts.add if phase == "start" else self.cuts.discard)(partition_ends(fault))
            self._announce_cuts(partition_ends(fault))
        elif phase == "end":  # the end of a pause (or the run)
            process = self.paused.pop(fault, None)
            pid = None if process is None else self.send(process, signal.SIGCONT)
        elif (process := self.find(fault.target)) is not None:
            if fault.action == "kill":
                self.spare(process)
                pid = self.send(process, signal.SIGKILL)
            else:
                self.paused[fault] = process
                pid = self.send(process, signal.SIGSTOP)
        what = (f"heal {fault.target}" if fault.action == "partition" else f"wake {fault.target}") \
            if phase == "end" else str(fault)
        struck = Struck(round(now_s, 3), self.step(), what, pid, time.time())
        self.struck.append(struck)
        with self.path.open("a") as file:
            file.write(json.dumps(dataclasses.asdict(struck)) + "\n")

    def _announce_cuts(self, ends: tuple[int, int]) -> None:
        """Write the links cut now to ``partition.json`` in the run folder (whole, then renamed) and
        tell the two robots of ``ends`` to read it (SIGUSR1: :func:`agents.process.cut_links`)."""
        path = self.path.with_name(PARTITION_FILE)
        path.with_suffix(".partial").write_text(json.dumps({"cut": sorted(self.cuts)}))
        path.with_suffix(".partial").replace(path)
        for robot in ends:
            if (process := self.find(robot_name(robot))) is not None:
                self.send(process, signal.SIGUSR1)

    def events(self) -> list[dict[str, object]]:
        """The faults carried out as run-log event records (``nemesis``, the fault as ``subject``)."""
        return [{"type": "event", "event": "nemesis", "step": struck.step, "subject": struck.fault,
                 "wall": struck.wall} for struck in self.struck]

    def wake_all(self) -> None:
        """Wake every process still paused (the run is ending)."""
        for process in self.paused.values():
            self.send(process, signal.SIGCONT)
        self.paused.clear()
