"""How a process joins the bus (bus/config.py): the embedded default and its checks."""

from __future__ import annotations

import json

import pytest

from ringtrack.bus.config import BusConfig, BusError, open_session


def setting(config: BusConfig, path: str) -> object:
    return json.loads(config.to_zenoh().get_json(path))


def test_the_embedded_default_is_a_loopback_peer_with_scouting_off() -> None:
    config = BusConfig()
    assert setting(config, "mode") == "peer"
    assert setting(config, "scouting/multicast/enabled") is False
    assert setting(config, "listen/endpoints") == ["tcp/127.0.0.1:0"]  # loopback only, a free port
    assert setting(config, "connect/endpoints") == []
    assert setting(config, "transport/shared_memory/enabled") is False  # no 16 MiB pool for a 3 kB digest


def test_a_client_listens_nowhere_and_a_router_listens_where_told() -> None:
    client = BusConfig(mode="client", connect=("tcp/10.0.0.1:7447",))
    assert setting(client, "listen/endpoints") == [] and setting(client, "connect/endpoints") == ["tcp/10.0.0.1:7447"]
    router = BusConfig(mode="router", listen=("tcp/0.0.0.0:7447",))
    assert setting(router, "mode") == "router" and setting(router, "listen/endpoints") == ["tcp/0.0.0.0:7447"]


@pytest.mark.parametrize(("arguments", "message"), [
    ({"listen": ("localhost",)}, "--listen 'localhost' is not an endpoint; write it like tcp/127.0.0.1:7447"),
    ({"connect": ("tcp/host",)}, "--connect 'tcp/host' is not an endpoint; write it like tcp/127.0.0.1:7447"),
    ({"mode": "client"}, "--mode client needs --connect ENDPOINT of a router or peer"),
])
def test_bad_settings_are_named(arguments: dict, message: str) -> None:
    with pytest.raises(BusError) as raised:
        BusConfig(**arguments)
    assert str(raised.value) == message


def test_a_session_opens_on_the_default_and_closes() -> None:
    with open_session(BusConfig()) as session:
        assert str(session.zid())
