"""The run log: one JSON-lines file per run, flushed record by record.

Records, one per line:

* ``header``: format version, source ("emulator" or "engine"), run id, the scenario as TOML, seed,
  team size, clock, step limit, library versions, start time (UTC);
* ``step``: the true state at the start of step k (``positions``, ``target``, ``live``), what each
  robot decided (``trigger`` mask, ``offset`` = gV - theta in radians and ``ages`` of its memory in
  steps, both before polling, ``centre`` it steered about and the ``covariance`` of that estimate,
  ``[xx, xy, yy]`` m^2, null where it knows the target), the robot-to-robot traffic each robot
  sent and received for that step (``sent_messages``, ``sent_bytes``, ``received_messages``,
  ``received_bytes``) and ``traffic`` [messages, bytes] per category of everything stamped with the
  step (bytes are null for the engine, which sends nothing: its counts follow from the protocol) and
  ``links``, the robot-to-robot messages of the step that were put on the bus, ``[kind, sender,
  receiver, messages]`` sorted (kind: request, reply, push; what the fault layer dropped is not
  there: see the ``dropped`` events) and ``energy_j``, each robot's radio energy of the steps before
  this one, [transmit, receive] joules (:mod:`bus.radio`; null: no command);
* ``event``: something that happened between steps (faults, crashes);
* ``end``: why and when the run ended, the traffic seen by the monitor per link, what every sender
  says it sent, rejected payloads, late messages and each robot's radio energy (``energy_j``:
  robot name -> [transmit, receive] joules, :mod:`bus.radio`).

A killed run leaves every complete line readable; :func:`read_log` ignores a torn last line and
checks every other record against the structs below, and each step's per-robot lists against the
team size, so that whatever reads a log may index its records without further checks.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import platform
from dataclasses import dataclass, field
from functools import cached_property
from importlib import metadata
from pathlib import Path
from typing import IO, Annotated, Any, Literal

import msgspec
import numpy as np

from ringtrack.agents.engine import FAULT_COLUMNS, History, fault_totals, link_traffic
from ringtrack.bus.faults import FAULTS
from ringtrack.bus.messages import EndReason
from ringtrack.tools.output.files import OutputError
from ringtrack.world.geometry import angle_of
from ringtrack.world.metrics import target_error, true_cerr
from ringtrack.world.scenario import Scenario, parse_scenario, resolve

FORMAT = 1
_encoder = msgspec.json.Encoder()


def versions() -> dict[str, str]:
    """Versions of Python and of the libraries a result depends on."""
    found = {"python": platform.python_version()}
    for name in ("ringtrack", "numpy", "eclipse-zenoh", "msgspec"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:  # pragma: no cover
            found[name] = "unknown"
    return found


class LogWriteError(OutputError):
    """The run log could not be written (a full disk, a file size limit); the message names the
    file and how many complete step records it holds. Its exit code tells a supervisor why a
    monitor stopped when the disk cannot hold the monitor's own message either."""

    exit_code = 3


class LogWriter:
    """Appends records to a run log, each line written whole at once (unbuffered). A write that
    fails (a full disk) cuts the file back to its last complete record, so the log stays readable,
    and raises :class:`LogWriteError`; the writer then refuses further records."""

    def __init__(self, path: Path, resume: bool = False) -> None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] | None = path.open("r+b" if resume else "wb", buffering=0)
        except OSError as error:
            raise LogWriteError(f"{path}: cannot {'resume' if resume else 'write'} the run log "
                                f"({error.strerror or error})") from None
        self.path = path
        self.steps_written = 0
        self._complete = 0  # bytes of complete records
        if resume:
            self._resume()

    def _resume(self) -> None:
        """Go on after the last complete record of the log (a torn last line, of a killed monitor, is
        cut off)."""
        assert self._file is not None
        data = self._file.read()
        self._complete = data.rfind(b"\n") + 1
        try:
            os.ftruncate(self._file.fileno(), self._complete)
            self._file.seek(self._complete)
        except OSError as error:
            self._fail(error)
        self.steps_written = last_logged_step(self.path)

    def write(self, record: dict[str, Any]) -> None:
        if self._file is None:
            raise LogWriteError(f"{self.path}: the run log was closed after a failed write")
        line = _encoder.encode(record) + b"\n"
        unwritten = memoryview(line)
        try:
            while unwritten:
                unwritten = unwritten[self._file.write(unwritten) or 0:]
        except OSError as error:
            self._fail(error)
        self._complete += len(line)
        self.steps_written += record.get("type") == "step"

    def _fail(self, error: OSError) -> None:
        assert self._file is not None
        with contextlib.suppress(OSError):
            os.ftruncate(self._file.fileno(), self._complete)
        with contextlib.suppress(OSError):
            self._file.close()
        self._file = None
        raise LogWriteError(f"{self.path}: cannot write the run log ({error.strerror or error}); it holds "
                            f"{self.steps_written} complete steps") from None

    def header(self, scenario: Scenario, source: str, run: int, seed: int, clock: str, steps: int) -> None:
        self.write(
            {
                "type": "header",
                "format": FORMAT,
                "source": source,
                "run": f"{run:08x}",
                "scenario_name": scenario.name,
                "scenario_toml": scenario.to_toml().decode(),
                "seed": seed,
                "robots": scenario.robots,
                "clock": clock,
                "steps": steps,
                "versions": versions(),
                "started_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            }
        )

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def step_record(
    step: int,
    time: float,
    positions: Any,
    target: Any,
    live: list[int],
    trigger: list[int | None],
    offset: list[float | None],
    ages: list[Any],
    centre: list[Any],
    sent: tuple[list[int], list[int] | None],
    received: tuple[list[int], list[int] | None],
    traffic: dict[str, list[int | None]],
    covariance: list[Any],
    links: list[list[Any]],
    energy: list[Any],
) -> dict[str, Any]:
    """A ``step`` record (see the module docstring for the fields); ``sent`` and ``received`` are
    (messages, bytes) per robot of robot-to-robot traffic, ``traffic`` [messages, bytes] per category
    of every message stamped with this step, ``links`` ``[kind, sender, receiver, messages]`` (sorted
    here)."""
    return {
        "type": "step",
        "step": step,
        "time": time,
        "positions": np.asarray(positions, dtype=float).tolist(),
        "target": np.asarray(target, dtype=float).tolist(),
        "live": live,
        "trigger": trigger,
        "offset": offset,
        "ages": ages,
        "centre": centre,
        "sent_messages": sent[0],
        "sent_bytes": sent[1],
        "received_messages": received[0],
        "received_bytes": received[1],
        "traffic": traffic,
        "covariance": covariance,
        "links": sorted(links),
        "energy_j": energy,
    }


def write_engine_log(path: Path, history: History, trial: int = 0) -> None:
    """Write one trial of an engine run in the run-log format (positions must be recorded)."""
    if history.positions is None:
        raise ValueError("the engine run did not record positions; run it with record_positions=True")
    scenario = history.scenario
    robots = scenario.robots
    sent, received = history.sent[:, trial], history.received[:, trial]
    estimation_messages = robots + 1 if scenario.centralized else 0
    covariances = history.covariances
    # J of the steps before each (what a robot's command reports): 0 at step 1
    energy = None if history.energy is None else np.cumsum(history.energy[:, trial], axis=0) - history.energy[:, trial]
    with LogWriter(path) as writer:
        writer.header(scenario, "engine", 0, history.seeds[trial], "engine", history.steps)
        assert history.estimates is not None
        for row in range(history.steps):
            writer.write(
                step_record(
                    step=row + 1,
                    time=row * scenario.control.dt,
                    positions=history.positions[row, trial],
                    target=history.targets[row, trial],
                    live=np.flatnonzero(history.live[row, trial]).tolist(),
                    trigger=history.triggers[row, trial].tolist(),
                    offset=history.offsets[row, trial].tolist(),
                    ages=history.ages[row, trial].tolist(),
                    centre=history.estimates[row, trial].tolist(),
                    sent=(sent[row].tolist(), None),
                    received=(received[row].tolist(), None),
                    traffic={"robot": [int(sent[row].sum()), None], "world": [2 * robots + 1, None],
                             "estimation": [estimation_messages, None]},
                    covariance=[None if np.isnan(packed).any() else packed.tolist()
                                for packed in (np.full((robots, 3), np.nan) if covariances is None
                                               else covariances[row, trial])],
                    links=engine_links(history, row, trial),
                    energy=[None] * robots if energy is None else energy[row].tolist(),
                )
            )
        writer.write({"type": "end", "steps": history.steps, "reason": EndReason.DONE, "wall_s": None,
                      "traffic": [list(row) for row in link_traffic(history, trial)], "senders": {}, "rejected": {},
                      "late": 0, "faults": fault_totals(history, trial), "energy_j": _engine_energy(history, trial)})


def engine_links(history: History, row: int, trial: int) -> list[list[Any]]:
    """The ``links`` of step ``row + 1`` of an engine trial: the request copies each robot published
    to its predecessor and successor, a reply to each, and the beliefs it pushed (as
    :func:`agents.engine.ring_traffic` counts them)."""
    assert history.requests is not None, "the links of a step are known of engine runs only"
    requests = history.requests[row, trial]
    pushes = np.zeros_like(requests) if history.pushes is None else history.pushes[row, trial]
    robots = len(requests)
    links: list[list[Any]] = []
    for robot in range(robots):
        for side, neighbour in ((0, (robot - 1) % robots), (1, (robot + 1) % robots)):
            if requests[robot, side]:
                links.append(["request", robot, neighbour, int(requests[robot, side])])
                links.append(["reply", neighbour, robot, int(requests[robot, side])])
            if pushes[robot, side]:
                links.append(["push", robot, neighbour, int(pushes[robot, side])])
    return links


def _engine_energy(history: History, trial: int) -> dict[str, list[float]]:
    """Each robot's radio energy over the trial, [transmit, receive] joules, by robot name."""
    if history.energy is None:
        return {}
    totals = history.energy[:, trial].sum(axis=0)
    return {f"r{robot}": totals[robot].tolist() for robot in range(len(totals))}


# ---------------------------------------------------------------------------- reading
Count = Annotated[int, msgspec.Meta(ge=0)]
Point = tuple[float, float]  # metres
Covariance = tuple[float, float, float]  # xx, xy, yy, m^2
LinkRow = tuple[Literal["request", "reply", "push"], int, int, Annotated[int, msgspec.Meta(ge=1)]]
TrafficRow = tuple[str, str, str, Count, Count | None]  # kind, source, destination, messages, bytes (None: engine)


class Record(msgspec.Struct, tag_field="type"):
    """What a valid record holds, by its ``type``; records stay plain dicts once checked."""


class HeaderRecord(Record, tag="header"):
    format: int
    source: str
    scenario_toml: str
    seed: int
    robots: Annotated[int, msgspec.Meta(ge=1)]
    clock: str
    steps: Count
    run: str = ""
    scenario_name: str = ""
    versions: dict[str, str] = {}
    started_utc: str = ""


class StepRecord(Record, tag="step"):
    step: Annotated[int, msgspec.Meta(ge=1)]
    time: float  # simulated seconds
    positions: list[Point]
    target: Point
    live: list[int]
    trigger: list[int | None]  # None: no command from that robot this step
    offset: list[float | None]  # rad
    ages: list[tuple[Count, Count] | None]  # steps
    centre: list[Point | None]
    sent_messages: list[Count]
    sent_bytes: list[Count] | None
    received_messages: list[Count]
    received_bytes: list[Count] | None
    traffic: dict[str, tuple[Count, Count | None]]
    covariance: list[Covariance | None] | None = None  # m^2; None: a log written before it was logged
    links: list[LinkRow] | None = None  # None: a log written before they were logged
    energy_j: list[tuple[float, float] | None] | None = None  # J so far; None: a log written before it was logged


PER_ROBOT = ("positions", "trigger", "offset", "ages", "centre", "sent_messages", "sent_bytes",
             "received_messages", "received_bytes", "covariance", "energy_j")  # step fields with one entry per robot


class EventRecord(Record, tag="event"):
    event: str  # dropped, duplicated, delayed (a fault on a link), joined, left
    step: Count
    subject: str | None = None
    sender: int | None = None
    receiver: int | None = None
    reason: str | None = None  # of a drop: drop, outage, range, gone, radio
    delay_s: float | None = None
    robot: str | None = None
    wall: float | None = None


class EndRecord(Record, tag="end"):
    steps: Count
    reason: str
    wall_s: float | None = None
    traffic: list[TrafficRow] = []
    senders: dict[str, list[TrafficRow]] = {}
    rejected: dict[str, int] = {}
    late: Count = 0
    dropped_ahead: Count = 0  # messages for steps too far ahead of the run (forged), dropped by the monitor
    rss_kib: dict[str, int] = {}
    consistent: bool | None = None
    faults: dict[str, int] = {}
    notes: dict[str, int] = {}
    rejected_by: dict[str, dict[str, int]] = {}
    energy_j: dict[str, tuple[float, float]] = {}


AnyRecord = HeaderRecord | StepRecord | EventRecord | EndRecord


@dataclass
class RunLog:
    """A run log read back: the header, every complete step record, events, both of them in file
    order (``records``: what the monitor fed its dashboard) and the end record (``None`` when the
    run was killed before it ended)."""

    header: dict[str, Any]
    steps: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)
    records: list[dict[str, Any]] = field(default_factory=list)
    end: dict[str, Any] | None = None
    label: str = "run log"  # names the file in error messages

    @cached_property
    def scenario(self) -> Scenario:
        label = f"{self.label}: line 1: scenario_toml"
        return resolve(parse_scenario(self.header["scenario_toml"], label), label)


class LogError(ValueError):
    """The file is not a run log; the message says why."""


def append_records(path: Path, records: list[dict[str, Any]]) -> bool:
    """Append ``records`` to a complete run log (a supervisor's own events, written once the run is
    over, after its end record); whether they were written. A write that fails (a full disk) cuts
    the file back to what it was, so the log stays readable."""
    try:
        with path.open("ab") as file:
            size = file.tell()
            try:
                file.write(b"".join(_encoder.encode(record) + b"\n" for record in records))
                file.flush()
            except OSError:
                file.truncate(size)
                return False
    except OSError:
        return False
    return True


TAIL_BYTES = 1 << 20  # how far back from a log's end last_logged_step looks


def last_logged_step(path: Path) -> int:
    """The number of the last step record a run log being written holds so far (0: none, or no
    file), read from its tail without decoding the rest."""
    try:
        with path.open("rb") as file:
            file.seek(0, os.SEEK_END)
            file.seek(max(0, file.tell() - TAIL_BYTES))
            tail = file.read()
    except OSError:
        return 0
    prefix = b'{"type":"step","step":'
    for line in reversed(tail.split(b"\n")):
        if line.startswith(prefix):
            digits = line[len(prefix):].split(b",", 1)[0]
            if digits.isdigit():
                return int(digits)
    return 0


def read_log(path: Path) -> RunLog:
    """Read and check a run log, skipping a torn last line (a killed run). A damaged record raises
    :class:`LogError`, a bad scenario :class:`~world.scenario.ScenarioError`, in one line naming
    the line and the problem."""
    if not path.is_file():
        raise LogError(f"{path}: no such run log; give RUN_FOLDER/log.jsonl")
    records = _decoded_lines(path)
    first = records[0][1] if records else None
    if not isinstance(first, dict) or first.get("type") != "header":
        where = f"line {records[0][0]}" if records else "line 1"
        raise LogError(f"{path}: {where}: no header record; this is not a ringtrack run log")
    if first.get("format") != FORMAT:
        raise LogError(f"{path}: log format {first.get('format')}, this ringtrack reads {FORMAT}")
    log = RunLog(header=first, label=str(path))
    _check(path, 1, first, HeaderRecord)
    robots = first["robots"]
    if log.scenario.robots != robots:
        raise _damaged(path, 1, f"header record: `robots` is {robots}, its scenario_toml has {log.scenario.robots}")
    for number, record in records[1:]:
        checked = _check(path, number, record, AnyRecord)
        if isinstance(checked, HeaderRecord):
            raise _damaged(path, number, "a second header record")
        if isinstance(checked, StepRecord):
            _check_team_size(path, number, record, robots)
            log.steps.append(record)
            log.records.append(record)
        elif isinstance(checked, EventRecord):
            if checked.event in FAULTS:
                _check_link_event(path, number, checked, robots)
            log.events.append(record)
            log.records.append(record)
        else:
            log.end = record
    return log


def _check_team_size(path: Path, number: int, step: dict[str, Any], robots: int) -> None:
    """Every per-robot list of a step record has one entry per robot."""
    for name in PER_ROBOT:
        values = step.get(name)
        if values is not None and len(values) != robots:
            raise _damaged(path, number,
                           f"step record: `{name}` has {len(values)} entries for a team of {robots} robots")
    for _kind, sender, receiver, _messages in step.get("links") or ():
        if not (0 <= sender < robots and 0 <= receiver < robots):
            raise _damaged(path, number, f"step record: `links` names robots {sender} and {receiver}; a team of "
                           f"{robots} has robots 0..{robots - 1}")


def _check_link_event(path: Path, number: int, event: EventRecord, robots: int) -> None:
    """A fault on a link names the robots at both ends, and a drop its reason (the dashboard shows it)."""
    if not all(robot is not None and 0 <= robot < robots for robot in (event.sender, event.receiver)):
        raise _damaged(path, number, f"{event.event} event: `sender` and `receiver` must be robots 0..{robots - 1}")
    if event.event == "dropped" and not event.reason:
        raise _damaged(path, number, "dropped event: `reason` is missing")


def _decoded_lines(path: Path) -> list[tuple[int, Any]]:
    """``(line number, decoded JSON value)`` of every non-blank line but a torn last one."""
    lines = path.read_bytes().split(b"\n")
    decoded = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            decoded.append((number, msgspec.json.decode(line)))
        except msgspec.DecodeError:
            if number >= len(lines) - 1:
                break  # torn last line of a killed run
            raise LogError(f"{path}: line {number} is not JSON; the file is damaged") from None
    return decoded


def _check(path: Path, number: int, record: Any, schema: Any) -> Record:
    """``record`` as a ``schema`` struct; a record that does not fit raises :class:`LogError`."""
    try:
        return msgspec.convert(record, schema)
    except msgspec.ValidationError as error:
        kind = record.get("type") if isinstance(record, dict) else None
        raise _damaged(path, number, f"{kind} record: {error}" if isinstance(kind, str) else str(error)) from None


def _damaged(path: Path, number: int, problem: str) -> LogError:
    return LogError(f"{path}: line {number}: {problem}; the file is damaged or not a ringtrack run log")


def history_from_log(log: RunLog) -> History:
    """The per-step arrays of a logged run, as the engine returns them (one trial)."""
    scenario = log.scenario
    positions = np.array([record["positions"] for record in log.steps], dtype=float)[:, None]
    targets = np.array([record["target"] for record in log.steps], dtype=float)[:, None]
    triggers = np.array([[value or 0 for value in record["trigger"]] for record in log.steps], dtype=np.uint8)
    offsets = np.array([[np.nan if value is None else value for value in record["offset"]] for record in log.steps])
    live = np.array([np.isin(np.arange(scenario.robots), record["live"]) for record in log.steps])
    ages = np.array([[value or [0, 0] for value in record["ages"]] for record in log.steps], dtype=np.int32)
    missing = [np.nan, np.nan]
    estimates = np.array([[centre or missing for centre in record["centre"]] for record in log.steps])[:, None]
    angles = angle_of(positions, targets[..., None, :])
    unknown = [np.nan] * 3
    covariances = np.array([[packed or unknown for packed in record.get("covariance") or [None] * scenario.robots]
                            for record in log.steps], dtype=float).reshape(len(log.steps), 1, scenario.robots, 3)
    return History(
        scenario=scenario,
        seeds=[log.header["seed"]],
        angles=np.unwrap(angles, axis=0),
        positions=positions,
        live=live[:, None],
        triggers=triggers[:, None],
        offsets=offsets[:, None],
        ages=ages[:, None],
        cerr_true=true_cerr(positions, targets),
        targets=targets,
        terr=target_error(estimates, targets),
        estimates=estimates,
        sent=np.array([record["sent_messages"] for record in log.steps], dtype=np.int64)[:, None],
        received=np.array([record["received_messages"] for record in log.steps], dtype=np.int64)[:, None],
        requests=None,
        faults=np.zeros((len(log.steps), 1, len(FAULT_COLUMNS)), dtype=np.int64),  # per run only: see the end record
        probes=np.zeros((len(log.steps), 1), dtype=np.int64),
        covariances=covariances,
    )
