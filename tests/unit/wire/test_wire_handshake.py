"""Handshake rules: matching topics and services, md5 wildcards, clear refusals."""

from __future__ import annotations

import pytest

from mrosd.errors import HandshakeError
from mrosd.wire.handshake import (
    check_publisher_reply,
    check_service_reply,
    error_header,
    publisher_reply,
    service_reply,
)
from mrosd.wire.header import ConnectionHeader

MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"
PUB = {
    "topic": "/chatter",
    "msg_type": "std_msgs/String",
    "md5sum": MD5,
    "message_definition": "string data\n",
    "callerid": "/talker",
    "latching": True,
}


def sub(**kw: str) -> ConnectionHeader:
    base = {"callerid": "/listener", "topic": "/chatter", "md5sum": MD5, "type": "std_msgs/String"}
    base.update(kw)
    return ConnectionHeader(**base)  # type: ignore[arg-type]


def test_a_matching_subscriber_gets_the_full_publisher_header() -> None:
    reply = publisher_reply(sub(), **PUB)  # type: ignore[arg-type]
    assert reply.md5sum == MD5
    assert reply.type == "std_msgs/String"
    assert reply.message_definition == "string data\n"
    assert reply.latching == "1"
    assert reply.callerid == "/talker"


def test_a_wildcard_subscriber_is_accepted() -> None:
    assert publisher_reply(sub(md5sum="*", type="*"), **PUB).md5sum == MD5  # type: ignore[arg-type]


def test_an_md5_mismatch_is_refused_naming_both_sums_and_types() -> None:
    with pytest.raises(HandshakeError, match=r"md5sums do not match: \[0+\] vs\. \[992c"):
        publisher_reply(sub(md5sum="0" * 32, type="my/String"), **PUB)  # type: ignore[arg-type]


def test_a_wildcard_md5_with_a_wrong_type_is_refused() -> None:
    with pytest.raises(HandshakeError, match="types do not match"):
        publisher_reply(sub(md5sum="*", type="std_msgs/Int32"), **PUB)  # type: ignore[arg-type]


def test_a_missing_field_and_a_wrong_topic_are_refused() -> None:
    with pytest.raises(HandshakeError, match="md5sum"):
        publisher_reply(ConnectionHeader(callerid="/x", topic="/chatter"), **PUB)  # type: ignore[arg-type]
    with pytest.raises(HandshakeError, match="not published"):
        publisher_reply(sub(topic="/other"), **PUB)  # type: ignore[arg-type]


def test_the_subscriber_reports_a_publishers_error_header() -> None:
    with pytest.raises(HandshakeError, match="refused \\[/chatter\\]: md5sums do not match"):
        check_publisher_reply(
            error_header("md5sums do not match"), topic="/chatter", msg_type="std_msgs/String", md5sum=MD5
        )


def test_the_subscriber_checks_the_publishers_md5() -> None:
    ok = ConnectionHeader(md5sum=MD5, type="std_msgs/String")
    assert check_publisher_reply(ok, topic="/c", msg_type="std_msgs/String", md5sum=MD5) is ok
    assert check_publisher_reply(ok, topic="/c", msg_type="*", md5sum="*") is ok
    with pytest.raises(HandshakeError):
        check_publisher_reply(ConnectionHeader(md5sum="1" * 32), topic="/c", msg_type="t/T", md5sum=MD5)


def test_services_match_on_md5_and_accept_probes_without_one() -> None:
    kw = {
        "service": "/add",
        "srv_type": "a/Add",
        "md5sum": "m",
        "request_type": "a/AddRequest",
        "response_type": "a/AddResponse",
        "callerid": "/srv",
    }
    reply = service_reply(ConnectionHeader(callerid="/c", service="/add", md5sum="m"), **kw)
    assert (reply.type, reply.request_type) == ("a/Add", "a/AddRequest")
    assert service_reply(ConnectionHeader(callerid="/c", service="/add", probe="1"), **kw).md5sum == "m"
    with pytest.raises(HandshakeError, match="md5sums do not match"):
        service_reply(ConnectionHeader(callerid="/c", service="/add", md5sum="x"), **kw)
    with pytest.raises(HandshakeError, match="refused"):
        check_service_reply(error_header("no"), service="/add", md5sum="m")
    with pytest.raises(HandshakeError, match="md5sums"):
        check_service_reply(ConnectionHeader(md5sum="x"), service="/add", md5sum="m")
