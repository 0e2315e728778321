"""Every TCPROS socket a node opens or accepts has TCP keepalive with rospy's timing (60 s idle, 10 s, 9 probes).

Without it a peer whose host vanishes (power cut, cable pulled) holds the connection forever. Checked on the
real sockets: the subscriber's outbound connection, the publisher's accepted one, a persistent service
client's connection and the service server's accepted one.
"""

from __future__ import annotations

import socket
from typing import Any

import pytest

import mrosd
from mrosd.msg import get_message_class, get_service_class
from mrosd.tcpros.sockopts import KEEPALIVE_COUNT, KEEPALIVE_IDLE, KEEPALIVE_INTERVAL
from tests.rosenv import needs_ros

pytestmark = needs_ros

String = get_message_class("std_msgs/String")
Trigger = get_service_class("std_srvs/Trigger")


def keepalive(transport: Any) -> tuple[int, int, int, int]:
    sock = transport.get_extra_info("socket")
    return (
        sock.getsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE),
        sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPIDLE),
        sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPINTVL),
        sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPCNT),
    )


EXPECTED = (1, KEEPALIVE_IDLE, KEEPALIVE_INTERVAL, KEEPALIVE_COUNT)


async def test_topic_and_service_sockets_have_keepalive_on_both_ends(
    rosmaster: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MROSD_SHM", "0")  # TCP sockets are under test: same-host mrosd nodes would share memory

    def n(name: str) -> mrosd.Node:
        return mrosd.Node(name, master_uri=rosmaster, host="127.0.0.1", argv=[], rosout=False, logger_services=False)

    async with n("ka_talker") as a, n("ka_listener") as b:
        pub = await a.advertise("/ka", String)
        sub = await b.subscribe("/ka", String)
        await sub.wait_for_publishers(1, timeout=10)
        await pub.wait_for_subscribers(1, timeout=10)
        (link,) = sub.links.values()
        assert link.proto is not None and link.proto.transport is not None
        assert keepalive(link.proto.transport) == EXPECTED  # subscriber -> publisher
        assert keepalive(pub.links[0].proto.transport) == EXPECTED  # accepted by the publisher's node

        srv = await a.advertise_service("/ka_srv", Trigger, lambda req: Trigger._response_class(success=True))
        proxy = b.service_proxy("/ka_srv", Trigger, persistent=True)
        try:
            assert (await proxy.call(Trigger._request_class())).success
            assert proxy._conn is not None
            assert keepalive(proxy._conn.writer.transport) == EXPECTED  # service client
            (server_side,) = srv.connections
            assert keepalive(server_side.transport) == EXPECTED  # accepted by the service's node
        finally:
            await proxy.aclose()
