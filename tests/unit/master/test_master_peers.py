"""Telling local peers apart by uid: the sock_diag message layout, the /proc/net/tcp parser, and real lookups."""

from __future__ import annotations

import os
import socket
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.master.peers import PeerUids, diag_request, is_local, parse_diag_reply, parse_proc_net_tcp

# Real lines (from this kernel), cut after the inode field.
PROC_TCP = """\
  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode
   0: 0100007F:2C4B 00000000:0000 0A 00000000:00000000 00:00000000 00000000     0        0 1
   1: 0100007F:A1B2 0100007F:2C4B 01 00000000:00000000 00:00000000 00000000  1000        0 2
   2: garbage
"""
PROC_TCP6 = (
    "  sl  local_address                         remote_address                        st tx_queue rx_queue ...\n"
    "   0: 00000000000000000000000001000000:D431 00000000000000000000000001000000:2C4B 01 "
    "00000000:00000000 00:00000000 00000000   999        0 3\n"
)


def test_proc_net_tcp_keys_each_socket_by_its_two_ends() -> None:
    table = parse_proc_net_tcp(PROC_TCP)
    assert table[(("127.0.0.1", 0xA1B2), ("127.0.0.1", 0x2C4B))] == 1000
    assert table[(("127.0.0.1", 0x2C4B), ("0.0.0.0", 0))] == 0
    assert len(table) == 2
    assert parse_proc_net_tcp(PROC_TCP6) == {(("::1", 0xD431), ("::1", 0x2C4B)): 999}
    assert parse_proc_net_tcp(PROC_TCP, remote_port=0x2C4B) == {(("127.0.0.1", 0xA1B2), ("127.0.0.1", 0x2C4B)): 1000}


@given(st.text())
def test_proc_net_tcp_parser_never_raises(text: str) -> None:
    parse_proc_net_tcp(text)


@given(st.binary(max_size=200))
def test_a_malformed_diag_reply_is_no_uid(data: bytes) -> None:
    assert parse_diag_reply(data) is None or isinstance(parse_diag_reply(data), int)


def test_diag_request_layout() -> None:
    msg = diag_request(("127.0.0.1", 40000), ("127.0.0.1", 11311), seq=7)
    length, kind, flags, seq, _ = struct.unpack_from("=IHHII", msg)
    assert length == len(msg) == 16 + 56 and kind == 20 and flags == 1 and seq == 7
    assert msg[16] == socket.AF_INET and msg[17] == socket.IPPROTO_TCP
    assert struct.unpack_from("!HH", msg, 24) == (40000, 11311)
    assert msg[28:32] == socket.inet_aton("127.0.0.1")


def test_is_local() -> None:
    assert is_local("127.0.0.1", "127.0.0.1") and is_local("127.3.2.1", "127.0.0.1") and is_local("::1", "::1")
    assert is_local("::ffff:127.0.0.1", "::") and is_local("192.168.1.5", "192.168.1.5")
    assert not is_local("192.168.1.6", "192.168.1.5")
    assert not is_local("", "")


@pytest.mark.parametrize("via", ["sock_diag", "proc"])
@pytest.mark.parametrize("family", [socket.AF_INET, socket.AF_INET6])
def test_the_uid_of_a_real_loopback_peer_is_found(via: str, family: int) -> None:
    host = "127.0.0.1" if family == socket.AF_INET else "::1"
    with socket.socket(family) as server:
        server.bind((host, 0))
        server.listen()
        with socket.create_connection(server.getsockname()[:2]) as client:
            conn, addr = server.accept()
            with conn:
                peers = PeerUids()
                if via == "proc":
                    peers._netlink_failed = True
                ours = conn.getsockname()[:2]
                assert peers.uid(addr[:2], ours) == os.geteuid()
                assert peers.uid((host, 1), ours) is None  # no such socket
                assert peers.table_parses == (1 if via == "proc" else 0)
                assert peers.uid(addr[:2], ours) == os.geteuid()
                assert peers.table_parses <= 1  # a hit never parses again
                peers.close()
        del client
