"""Hostile peers of the shared-memory transport: the kernel and the checks keep every other party safe.

A subscriber cannot resize or write the ring (sealed memfd, read-only descriptor, F_SEAL_FUTURE_WRITE even
against reopening it read-write through /proc); a publisher that sends an unsealed or oversized file, lies
about lengths or heads, or speaks garbage ends only its own connection, with one line, and never makes the
subscriber read out of bounds; a subscriber that sends garbage, or nothing at all, is closed and the publisher
serves the others. A subscriber that lies in its acknowledgement page, or stops reading, costs only itself:
the publisher never waits for it beyond its queue, and the others are served.
"""

from __future__ import annotations

import array
import asyncio
import contextlib
import errno
import logging
import mmap
import os
import secrets
import socket
import threading
from collections.abc import Callable

import pytest

from mrosd import backports
from mrosd.errors import RemoteProtocolError
from mrosd.shm import ShmPublisherEndpoint, ShmSubscriberConnection, control
from mrosd.shm import door as shm_door
from mrosd.shm import publisher as shm_publisher
from mrosd.shm import subscriber as shm_subscriber
from mrosd.shm.negotiate import VERSION, ShmAnswer
from mrosd.shm.ring import RingLayout, ring_size
from mrosd.shm.segment import ACK_PAGE, MappedRing, RingSegment
from mrosd.wire.header import ConnectionHeader, encode_header

HEADER = ConnectionHeader(callerid="/victim", topic="/t", md5sum="*", type="*")


# the ring's file ------------------------------------------------------------------------------------------


def test_the_ring_cannot_be_resized_by_anyone() -> None:
    seg = RingSegment("hostile", 3, 4096)
    reader = seg.reader_fd()
    try:
        for fd in (seg.fd, reader):
            with pytest.raises(OSError) as exc:
                os.ftruncate(fd, 1)
            assert exc.value.errno in (errno.EPERM, errno.EINVAL, errno.EBADF)
        with pytest.raises(PermissionError):
            os.ftruncate(seg.fd, seg.size * 2)
    finally:
        os.close(reader)
        seg.close()


def test_a_reader_descriptor_cannot_be_made_writable_even_through_proc() -> None:
    seg = RingSegment("hostile", 3, 4096)
    reader = seg.reader_fd()
    try:
        with pytest.raises(PermissionError):
            mmap.mmap(reader, seg.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        rw = os.open(f"/proc/self/fd/{reader}", os.O_RDWR)  # same uid: the open itself succeeds
        try:
            with pytest.raises(PermissionError):
                os.pwrite(rw, b"evil", 0)
            with pytest.raises(PermissionError):
                mmap.mmap(rw, seg.size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        finally:
            os.close(rw)
        mapped = MappedRing(os.dup(reader), 1 << 30)
        with pytest.raises(TypeError):
            mapped.layout.buf[0] = 0  # the subscriber's mapping is read-only
        mapped.close()
        seg.layout.write(b"the publisher still writes")  # its mapping predates the seal
    finally:
        os.close(reader)
        seg.close()


def test_a_subscriber_refuses_files_that_could_hurt_it() -> None:
    plain = os.memfd_create("mrosd-shm-unsealed", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    os.ftruncate(plain, 4096)
    with pytest.raises(RemoteProtocolError, match="not sealed"):
        MappedRing(plain, 1 << 30)
    r, w = os.pipe()
    os.close(w)
    with pytest.raises(RemoteProtocolError, match="not a sealable memfd"):
        MappedRing(r, 1 << 30)
    seg = RingSegment("big", 2, 1 << 20)
    with pytest.raises(RemoteProtocolError, match="at most"):
        MappedRing(seg.reader_fd(), 1 << 20)
    seg.close()


# hostile publishers ---------------------------------------------------------------------------------------


def sealed(raw: bytes) -> int:
    fd = os.memfd_create("mrosd-shm-fake", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    os.pwrite(fd, raw, 0)
    import fcntl

    fcntl.fcntl(fd, fcntl.F_ADD_SEALS, fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_WRITE)
    return fd


def ack_page(size: int = ACK_PAGE, seal: bool = True) -> int:
    fd = os.memfd_create("mrosd-shm-fake-ack", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    os.ftruncate(fd, size)
    if seal:
        import fcntl

        fcntl.fcntl(fd, fcntl.F_ADD_SEALS, fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW)
    return fd


def pipe_end() -> int:
    r, w = os.pipe()
    os.close(r)
    return w


#: the fake publishers' ends of their wake-up pairs, held for the test session (a closed end ends the connection)
_HELD: list[socket.socket] = []


def wake_pair_end() -> int:
    """The subscriber's end of a wake-up socket pair made here (our end is held, never written)."""
    mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    _HELD.append(mine)
    return theirs.detach()


def third_party_socket() -> int:
    """A socket connected to someone else's listening socket: our wake-ups would land there."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind("\0mrosd-shm-third-party-" + secrets.token_hex(6))
    listener.listen(1)
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    conn.connect(listener.getsockname())
    listener.close()
    return conn.detach()


def attached_fds(ring_fd: int, ack: int | None = None, wake: int | None = None) -> list[int]:
    """What an honest Attached carries beside the ring: an acknowledgement page and the subscriber's end of the
    publisher's wake-up socket pair."""
    return [ring_fd, ack_page() if ack is None else ack, wake_pair_end() if wake is None else wake]


def lying_ring(mutate: Callable[[RingLayout], None]) -> bytes:
    buf = bytearray(ring_size(2, 64))
    ring = RingLayout.initialize(memoryview(buf), 2, 64)
    ring.write(b"honest")
    mutate(ring)
    ring.release()
    return bytes(buf)


async def fake_publisher(reply: Callable[[socket.socket], None]) -> tuple[ShmAnswer, asyncio.Task[None]]:
    """A process-local impostor on an abstract socket: reads the Attach, then runs ``reply``."""
    address = "@mrosd-shm-fake-" + secrets.token_hex(6)
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind("\0" + address[1:])
    server.listen(1)
    server.setblocking(False)
    loop = asyncio.get_running_loop()

    async def serve() -> None:
        try:
            conn, _ = await loop.sock_accept(server)
        finally:
            server.close()
        try:
            conn.setblocking(False)
            await loop.sock_recv(conn, 65536)
            reply(conn)
            await asyncio.sleep(5)
        finally:
            conn.close()

    return ShmAnswer(version=VERSION, address=address, token="t" * 32), loop.create_task(serve())


async def stop(task: asyncio.Task[None]) -> None:
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)


def send(conn: socket.socket, msg: control.Message, fds: list[int]) -> None:
    anc = [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", fds).tobytes())] if fds else []
    conn.sendmsg([control.encode(msg)], anc)
    for fd in fds:
        os.close(fd)


ATTACHED = control.Attached(header=encode_header(ConnectionHeader(callerid="/liar"))[4:], first=1)


@pytest.mark.parametrize(
    ("mutate", "why"),
    [
        (lambda r: r.words[0].__setitem__(1, 1 << 40), "claims a"),
        (lambda r: r.words[0].__setitem__(0, 0), "holds sequence"),
    ],
)
async def test_a_publisher_that_lies_about_the_ring_ends_only_its_connection(
    mutate: Callable[[RingLayout], None], why: str, caplog: pytest.LogCaptureFixture
) -> None:
    answer, task = await fake_publisher(lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(mutate)))))
    got: list[bytes] = []
    with caplog.at_level(logging.WARNING):
        conn = await ShmSubscriberConnection.attach(answer, HEADER, on_frame=got.append)
        await backports.wait_for(asyncio.shield(conn.closed), 5)
    assert why in conn.error and not got
    assert any(why in r.getMessage() for r in caplog.records)
    await stop(task)


@pytest.mark.parametrize(
    ("reply", "match"),
    [
        (lambda c: send(c, ATTACHED, attached_fds(os.memfd_create("x", os.MFD_ALLOW_SEALING))), "not sealed"),
        (lambda c: send(c, ATTACHED, []), "file descriptors"),
        (lambda c: send(c, ATTACHED, [sealed(lying_ring(lambda r: None))]), "file descriptors"),
        # the acknowledgement page: unsealed (could be shrunk under our mapping), or not one page
        (lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None)), ack_page(seal=False))), "4 KiB"),
        (lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None)), ack_page(1 << 20))), "4 KiB"),
        # a pipe or an eventfd for the wake-ups both ways: the publisher could make either block our writes
        (lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None)), wake=pipe_end())), "socket"),
        (lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None)), wake=os.eventfd(0))), "socket"),
        # a socket connected to a third party: our wake-ups would be bytes sent to someone else
        (
            lambda c: send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None)), wake=third_party_socket())),
            "socket pair",
        ),
        (lambda c: c.send(b"\x05\x00\x00\x00garba"), "bad shared-memory control message"),
        (lambda c: c.send(b"\xff\xff\xff\x7f"), "limit"),
        (lambda c: send(c, control.Ring(slots=2), [sealed(lying_ring(lambda r: None))]), "expected Attached"),
        (lambda c: c.close(), "closed the connection"),
    ],
)
async def test_a_publisher_that_breaks_the_handshake_is_a_one_line_error(
    reply: Callable[[socket.socket], None], match: str
) -> None:
    answer, task = await fake_publisher(reply)
    with pytest.raises(RemoteProtocolError, match=match):
        await ShmSubscriberConnection.attach(answer, HEADER, timeout=5)
    await stop(task)


async def test_a_publisher_that_never_answers_times_out() -> None:
    answer, task = await fake_publisher(lambda c: None)
    with pytest.raises(TimeoutError):
        await ShmSubscriberConnection.attach(answer, HEADER, timeout=0.3)
    await stop(task)


# hostile subscribers --------------------------------------------------------------------------------------


async def raw_client(ep: ShmPublisherEndpoint) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.setblocking(False)
    await asyncio.get_running_loop().sock_connect(sock, "\0" + ep.address[1:])
    return sock


async def closed_by_peer(sock: socket.socket) -> bytes:
    loop = asyncio.get_running_loop()
    data = b""
    async with backports.timeout(5):
        while chunk := await loop.sock_recv(sock, 65536):
            data += chunk
    return data


async def test_hostile_subscribers_are_closed_and_the_others_served(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(shm_door, "ATTACH_TIMEOUT", 0.3)
    ep = ShmPublisherEndpoint("/t", queue_size=4)
    await ep.start()
    good = await ShmSubscriberConnection.attach(ShmAnswer(version=VERSION, address=ep.address, token=ep.token), HEADER)
    try:
        attach = control.Attach(token=ep.token, header=encode_header(HEADER)[4:])
        # descriptors with the Attach (version 2 sent an eventfd): closed unused, and the publisher goes on
        pipe_sock = await raw_client(ep)
        r, w = os.pipe()
        send(pipe_sock, attach, [w])
        async with backports.timeout(5):
            assert b"attached" in await asyncio.get_running_loop().sock_recv(pipe_sock, 65536)
        os.set_blocking(r, False)
        assert os.read(r, 1) == b""  # nobody holds the write end any more: the publisher closed it
        # garbage, a frame bigger than allowed, fds without a frame, silence
        for payload in (b"\x03\x00\x00\x00abc", b"\xff\xff\xff\xff", b""):
            sock = await raw_client(ep)
            if payload:
                sock.send(payload)
            await closed_by_peer(sock)
            sock.close()
        sock = await raw_client(ep)
        send(sock, control.Progress(dropped=1, received=1), [])  # not an Attach
        await closed_by_peer(sock)
        sock.close()
        pipe_sock.close()
        # an attached subscriber that claims absurd drops is capped, then one that sends garbage is dropped
        answer = ShmAnswer(version=VERSION, address=ep.address, token=ep.token)
        liar = await ShmSubscriberConnection.attach(answer, HEADER)
        assert liar._channel is not None
        liar._channel.sock.send(control.encode(control.Progress(dropped=1 << 63, received=0)))
        await asyncio.sleep(0.05)
        assert max(s["dropped"] for s in ep.stats()) == 1 << 62
        liar._channel.sock.send(b"\x01\x00\x00\x00\xc1")
        await backports.wait_for(asyncio.shield(liar.closed), 5)
        assert len(ep.links) == 1
        ep.publish(b"still served")
        assert await backports.wait_for(anext(good), 5) == b"still served"
        assert not ep.door._pending
    finally:
        await good.aclose()
        await ep.aclose()


async def test_a_publisher_that_floods_replacement_rings_is_cut_off() -> None:
    def flood(c: socket.socket) -> None:
        send(c, ATTACHED, attached_fds(sealed(lying_ring(lambda r: None))))
        for _ in range(shm_subscriber.MAX_NEXT_RINGS + 1):
            send(c, control.Ring(slots=2), [sealed(lying_ring(lambda r: None))])

    answer, task = await fake_publisher(flood)
    try:
        conn = await ShmSubscriberConnection.attach(answer, HEADER)  # not iterated: nothing is switched to
    except RemoteProtocolError as exc:
        assert "before we were attached" in str(exc)
    else:
        await backports.wait_for(asyncio.shield(conn.closed), 5)
        assert "too often" in conn.error
    await stop(task)


async def test_a_subscriber_that_lies_in_its_acknowledgement_page_costs_only_itself(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(shm_publisher, "STALL", 0.05)
    ep = ShmPublisherEndpoint("/t", queue_size=1000)
    await ep.start()
    shm_answer = ShmAnswer(version=VERSION, address=ep.address, token=ep.token)
    liar = await ShmSubscriberConnection.attach(shm_answer, HEADER)  # never reads
    got: list[bytes] = []
    honest = await ShmSubscriberConnection.attach(shm_answer, HEADER, on_frame=lambda b: got.append(bytes(b)))
    try:
        assert liar._ack is not None and liar._wake is not None
        sent = [i.to_bytes(2, "little") * 5000 for i in range(300)]
        for i, body in enumerate(sent):
            if i == 0:
                liar._ack.write((1 << 64) - 1)  # "I have read messages that do not exist yet"
            elif i == 100:
                liar._ack.write(0)  # "I have read nothing at all"
            elif i == 200:
                for _ in range(10_000):  # and wakes the publisher for nothing, over and over
                    with contextlib.suppress(BlockingIOError):
                        liar._wake.send(b"\x01", socket.MSG_DONTWAIT)
            ep.publish(body)
            assert len(ep.backlog) <= 1000
            await asyncio.sleep(0.0005)
        async with backports.timeout(10):
            while len(got) < len(sent):  # noqa: ASYNC110 - filled by the connection's callback
                await asyncio.sleep(0.01)
        assert got == sent and honest.dropped == 0
        assert not ep.backlog
    finally:
        await liar.aclose()
        await honest.aclose()
        await ep.aclose()


async def test_a_subscriber_that_steals_wake_ups_from_its_descriptor_takes_only_its_own(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    woken_by: list[int] = []
    real = ShmPublisherEndpoint._on_progress

    def spy(self: ShmPublisherEndpoint, link: shm_publisher.ShmSubscriberLink) -> None:
        woken_by.append(link.id)
        real(self, link)

    monkeypatch.setattr(ShmPublisherEndpoint, "_on_progress", spy)
    ep = ShmPublisherEndpoint("/t", queue_size=1000)
    await ep.start()
    shm_answer = ShmAnswer(version=VERSION, address=ep.address, token=ep.token)
    thief_got: list[int] = []
    thief = await ShmSubscriberConnection.attach(shm_answer, HEADER, on_frame=lambda b: thief_got.append(len(b)))
    got: list[bytes] = []
    honest = await ShmSubscriberConnection.attach(shm_answer, HEADER, on_frame=lambda b: got.append(bytes(b)))
    stop = threading.Event()
    assert thief._wake is not None
    fd = os.dup(thief._wake.fileno())

    def steal() -> None:  # drains everything it can from the descriptor it was given, all the time
        while not stop.is_set():
            with contextlib.suppress(OSError):
                os.read(fd, 8)
        os.close(fd)

    stealer = threading.Thread(target=steal, daemon=True)
    stealer.start()
    try:
        honest_id = ep.links[1].id
        sent = [i.to_bytes(2, "little") * 100_000 for i in range(200)]
        for body in sent:  # a burst far longer than the ring: it waits in the publisher's queue
            ep.publish(body)
        assert ep.backlog
        async with backports.timeout(10):
            while len(got) < len(sent):  # noqa: ASYNC110 - filled by the connection's callback
                await asyncio.sleep(0.01)
        assert got == sent and honest.dropped == 0
        assert honest_id in woken_by  # the honest subscriber's own wake-ups reached the publisher
    finally:
        stop.set()
        stealer.join(5)
        await thief.aclose()
        await honest.aclose()
        await ep.aclose()
