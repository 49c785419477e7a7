"""Where Foxglove samples go: an MCAP file, a live Foxglove WebSocket server, or both.

:class:`FoxgloveSink` is handed run-log records one at a time (the monitor's ``on_record``, or every
record of a log read back by ``export --mcap``), translates each (:class:`tools.viz.scene.Translator`)
and logs the samples on its channels, in a context of its own: the MCAP file and the server see the
same channels. The server binds 127.0.0.1 unless a host is named; port 0 takes a free port
(:attr:`FoxgloveSink.port`).
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import threading
import time
from pathlib import Path
from typing import Any

from ringtrack.tools.runlog.log import RunLog
from ringtrack.tools.viz.scene import ENERGY_SCHEMA, METRICS_SCHEMA, TOPICS, Translator
from ringtrack.world.scenario import Scenario

try:  # the viz extra (tools.viz.extra.require_sdk says what to install)
    import foxglove
    from foxglove import channels as fc
except ImportError:  # pragma: no cover
    pass

JSON_SCHEMAS = {"/metrics": METRICS_SCHEMA, "/energy": ENERGY_SCHEMA}
SERVER_NAME = "ringtrack"


def _channel(topic: str, schema: str, context: foxglove.Context) -> Any:
    if schema == "json":
        return foxglove.Channel(topic, schema=JSON_SCHEMAS[topic], context=context)
    return getattr(fc, f"{schema}Channel")(topic, context=context)


def idle_priority() -> None:
    """Run this process only when a core would otherwise idle (Linux ``SCHED_IDLE``): a live team's
    world and robots always come first. Elsewhere, nothing."""
    if hasattr(os, "SCHED_IDLE"):
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        except OSError:  # a sandbox may refuse it: the thread then runs at the process's priority
            pass


class FoxgloveSink:
    """Records and/or serves a run: ``record`` an MCAP file to write (replaced if it exists),
    ``serve`` ``(host, port)`` of a Foxglove WebSocket server to start. Call it with each run-log
    record, in file order; :meth:`close` finishes the file and stops the server."""

    def __init__(self, scenario: Scenario, record: Path | None = None, serve: tuple[str, int] | None = None) -> None:
        self.translator = Translator(scenario)
        self.context = foxglove.Context()
        self.channels = {topic: _channel(topic, schema, self.context) for topic, schema in TOPICS.items()}
        self.writer = None if record is None else foxglove.open_mcap(record, allow_overwrite=True,
                                                                     context=self.context)
        self.server = None if serve is None else foxglove.start_server(
            name=SERVER_NAME, host=serve[0], port=serve[1], context=self.context)

    @property
    def port(self) -> int | None:
        """The port the live server listens on (None: no server)."""
        return None if self.server is None else self.server.port

    def __call__(self, record: dict[str, Any]) -> None:
        for sample in self.translator.translate(record):
            self.channels[sample.topic].log(sample.message, log_time=sample.log_time_ns)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self) -> FoxgloveSink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


LIVE_RATE_HZ = 30.0  # the live view draws at most this many steps per wall second (a screen's rate)


class LiveServer:
    """A live Foxglove WebSocket server (:class:`FoxgloveSink` with ``serve``) in a process of its own
    at idle priority (:func:`idle_priority`), for a live team's monitor. The monitor only queues each
    record (a thread of its own feeds the pipe, so a busy machine never holds the monitor up); the
    view draws every event and the latest step it can keep up with, at most :data:`LIVE_RATE_HZ` steps
    a wall second (the steps between still count in the running totals), so that a lockstep team
    running hundreds of steps a second pays for a screen's worth. :meth:`close` waits until the
    queued records are handed over; if the monitor dies, the view ends with it."""

    def __init__(self, scenario: Scenario, serve: tuple[str, int]) -> None:
        context = multiprocessing.get_context("spawn")  # the monitor runs Zenoh's threads: no fork
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_live_view, args=(scenario, serve, child), name="ringtrack-foxglove",
                                       daemon=True)
        self.process.start()
        child.close()
        self.port: int = self.connection.recv()  # once the server listens
        self.queue: queue.SimpleQueue[dict[str, Any] | None] = queue.SimpleQueue()
        self.feeder = threading.Thread(target=self._feed, name="foxglove-feed", daemon=True)
        self.feeder.start()

    def __call__(self, record: dict[str, Any]) -> None:
        self.queue.put(record)

    def _feed(self) -> None:
        """Send the queued records down the pipe, then the None that :meth:`close` queues."""
        while True:
            record = self.queue.get()
            try:
                self.connection.send(record)
            except OSError:  # the view's process is gone
                return
            if record is None:
                return

    def close(self) -> None:
        self.queue.put(None)
        self.feeder.join()
        if self.process.is_alive():
            try:
                self.connection.recv()  # the last records drawn, the server stopped
            except EOFError:
                pass
        self.process.join()


def _live_view(scenario: Scenario, serve: tuple[str, int], connection: Any) -> None:
    """The body of a :class:`LiveServer`: draw what the monitor sends until None or its end. A Ctrl-C
    reaches the whole process group: the monitor decides when this process stops."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    idle_priority()
    period = 1.0 / LIVE_RATE_HZ
    drawn_at = 0.0
    with FoxgloveSink(scenario, serve=serve) as sink:
        connection.send(sink.port)
        ended = False
        while not ended:
            try:
                batch = [connection.recv()]
                while connection.poll(0):
                    batch.append(connection.recv())
            except EOFError:  # the monitor is gone
                return
            ended = batch[-1] is None
            records = [record for record in batch if record is not None]
            steps = [index for index, record in enumerate(records) if record.get("type") == "step"]
            latest = steps[-1] if steps and (ended or time.monotonic() - drawn_at >= period) else None
            for index, record in enumerate(records):
                if index in steps and index != latest:
                    sink.translator.skip(record)
                else:
                    sink(record)
            if latest is not None:
                drawn_at = time.monotonic()
    connection.send("closed")


def write_mcap(log: RunLog, path: Path) -> None:
    """Write a run ``log`` as MCAP to ``path``: its step and event records in the order of their steps
    (file order within a step: a supervisor's events, appended after the end, go where they happened),
    then its end (``export --mcap``, and ``spawn --record`` once the run's log is complete)."""
    with FoxgloveSink(log.scenario, record=path) as sink:
        for record in [*sorted(log.records, key=lambda record: record["step"]), *([log.end] if log.end else [])]:
            sink(record)
