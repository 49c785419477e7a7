"""Where Foxglove samples go: an MCAP file, a live Foxglove WebSocket server, or both.

:class:`FoxgloveSink` is handed run-log records one at a time (the monitor's ``on_record``, or every
record of a log read back by ``export --mcap``), translates each (:class:`tools.viz.scene.Translator`)
and logs the samples on its channels, in a context of its own: the MCAP file and the server see the
same channels. The server binds 127.0.0.1 unless a host is named; port 0 takes a free port
(:attr:`FoxgloveSink.port`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

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


def write_mcap(scenario: Scenario, records: Iterable[dict[str, Any]], path: Path) -> None:
    """Write a run's records (in file order) as MCAP to ``path``."""
    with FoxgloveSink(scenario, record=path) as sink:
        for record in records:
            sink(record)
