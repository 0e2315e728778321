"""The client's sans-IO connection core: frames in pieces, descriptors beside them, pushes applied, bad input."""

from __future__ import annotations

import os

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import IxmError, RemoteProtocolError
from mrosd.ixm.channel import MAX_PENDING_FDS
from mrosd.ixm.connection import TRUSTED_UIDS_ENV, ClientConnection, trusted_uids
from mrosd.ixm.protocol import Error, Listing, Ok, Opened, WakeList, encode


def test_replies_come_out_whole_from_bytes_fed_one_at_a_time() -> None:
    conn = ClientConnection()
    data = encode(Ok()) + encode(Error("limit", "too many")) + encode(Listing(processes=[], segments=[]))
    got = []
    for i in range(len(data)):
        conn.receive(data[i : i + 1])
        while (reply := conn.next_reply()) is not None:
            got.append(reply)
    assert got == [Ok(), Error("limit", "too many"), Listing(processes=[], segments=[])]


def test_a_push_for_a_key_not_open_here_closes_its_descriptors_and_counts_as_applied() -> None:
    conn = ClientConnection()
    r, w = os.pipe()
    conn.receive(encode(WakeList(key="/gone", generation=3, count=2)) + encode(Ok()), [r, w])
    assert conn.next_reply() == Ok()
    assert conn.pushes.applied == 3
    for fd in (r, w):
        with pytest.raises(OSError):
            os.fstat(fd)


def test_a_reply_announcing_descriptors_that_never_came_is_a_protocol_error() -> None:
    conn = ClientConnection()
    conn.receive(encode(WakeList(key="/k", generation=1, count=1)))
    with pytest.raises(RemoteProtocolError, match="announced 1 file descriptors but 0 arrived"):
        conn.next_reply()
    opened = Opened(key="/k", type="int32", count=0, max_size=0, capacity=4, mode="r", shm_name="memfd:x")
    with pytest.raises(RemoteProtocolError, match="announced 1"):
        conn.opened(opened, None)


def test_too_many_unclaimed_descriptors_are_refused() -> None:
    conn = ClientConnection()
    fd = os.open(os.devnull, os.O_RDONLY)
    try:
        with pytest.raises(RemoteProtocolError, match="unclaimed"):
            conn.receive(b"", [fd] * (MAX_PENDING_FDS + 1))
    finally:
        os.close(fd)


def test_a_refused_open_raises_the_daemons_message_and_closes_the_eventfd() -> None:
    conn = ClientConnection()
    efd = os.eventfd(0)
    with pytest.raises(IxmError, match="uid 7 already holds"):
        conn.opened(Error("limit", "uid 7 already holds 36 IXM keys"), efd)
    with pytest.raises(OSError):
        os.fstat(efd)


def test_trusted_uids_are_root_ours_the_given_and_the_environments(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TRUSTED_UIDS_ENV, "1000, 1001")
    assert trusted_uids([42]) == {0, os.geteuid(), 42, 1000, 1001}
    monkeypatch.setenv(TRUSTED_UIDS_ENV, "robot")
    with pytest.raises(IxmError, match="must list uids"):
        trusted_uids()


@given(st.binary(max_size=300))
def test_arbitrary_bytes_from_the_daemon_never_raise_anything_but_protocol_errors(data: bytes) -> None:
    conn = ClientConnection(max_reply=256)
    try:
        conn.receive(data)
        while conn.next_reply() is not None:
            pass
    except RemoteProtocolError:
        pass
    finally:
        conn.close()
