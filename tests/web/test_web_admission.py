"""The pure rules of ``mrosd.web.admission``: which Host and Origin a handshake may carry, and the slots."""

from __future__ import annotations

import pytest

from mrosd.web.admission import Admission, OriginGate, host_name


@pytest.mark.parametrize(
    ("header", "name"),
    [("127.0.0.1:8765", "127.0.0.1"), ("[::1]:9090", "::1"), ("LocalHost.:80", "localhost"), ("robot", "robot")],
)
def test_host_name(header: str, name: str) -> None:
    assert host_name(header) == name


def test_hosts_answered_to() -> None:
    gate = OriginGate(hostnames=["Robot.local"])
    for host in (None, "127.0.0.1:8765", "[::1]:9090", "10.1.2.3", "localhost:8765", "robot.local:9090"):
        assert gate.host_ok(host), host
    for host in ("attacker.test:8765", "robot.local.attacker.test", "localhost.attacker.test", ""):
        assert not gate.host_ok(host), host


def test_origins() -> None:
    gate = OriginGate(hostnames=["robot.local"], allowed_origins=["https://app.foxglove.dev/"])
    own = [
        ("127.0.0.1:9090", "http://127.0.0.1:8765"),
        ("localhost:8765", "http://localhost:8765"),
        ("[::1]:9090", "http://[::1]:8765"),
        ("robot.local:9090", "http://robot.local:8765"),
        ("127.0.0.1:9090", None),  # not a browser
        ("127.0.0.1:9090", "https://app.foxglove.dev"),
        ("127.0.0.1:9090", "http://127.0.0.1:9090"),  # the socket's own origin: websocket-client (ros-mcp)
        ("[::1]:9090", "http://[::1]:9090"),
    ]
    for host, origin in own:
        assert gate.refusal(host, origin, 8765) is None, (host, origin)
    foreign = [
        ("127.0.0.1:9090", "http://127.0.0.1:8000"),  # another site on this machine
        ("127.0.0.1:9090", "http://localhost:8765"),  # our page by another name than the socket's
        ("127.0.0.1:9090", "http://10.0.0.6:8765"),  # another robot's page
        ("127.0.0.1:9090", "null"),  # a sandboxed frame or a file
        ("127.0.0.1:9090", "http://attacker.test:8765"),
        ("attacker.test:8765", "http://attacker.test:8765"),  # DNS rebinding: the Host is refused
        ("attacker.test:8765", None),
        ("127.0.0.1:9090", "http://127.0.0.1:notaport"),
        ("127.0.0.1:9090", "http://127.0.0.1:9091"),  # a page of the next port
        ("127.0.0.1:9090", "http://localhost:9090"),  # the socket's port by another name
        ("127.0.0.1", "http://127.0.0.1"),  # no port in Host: only the page's port counts
    ]
    for host, origin in foreign:
        assert gate.refusal(host, origin, 8765) is not None, (host, origin)
    assert OriginGate(allowed_origins=["*"]).refusal("127.0.0.1", "http://evil.example", 8765) is None


def test_client_slots_in_all_and_per_address() -> None:
    adm = Admission(max_clients=4, per_address=3)
    assert [adm.admit("a") for _ in range(3)] == [None] * 3
    assert adm.admit("a") is not None  # per address
    assert adm.admit("b") is None
    assert adm.admit("c") is not None  # in all
    adm.release("a")
    assert adm.admit("c") is None
    assert Admission(max_clients=64).address_cap == 48


def test_pending_evicts_the_oldest_of_the_address_then_of_all() -> None:
    adm = Admission(max_clients=1, max_pending=4, pending_per_address=2)
    assert adm.pend("a1", "a") == []
    assert adm.pend("a2", "a") == []
    assert adm.pend("a3", "a") == ["a1"]
    assert adm.pend("b1", "b") == []
    assert adm.pend("c1", "c") == []
    assert adm.pend("d1", "d") == ["a2"]
    assert adm.pending == 4
    adm.settle("a3")
    adm.settle("a3")  # twice: nothing
    assert adm.pending_keys() == ["b1", "c1", "d1"]
    assert adm.clients == 0  # pending connections never hold a client slot
