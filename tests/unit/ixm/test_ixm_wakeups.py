"""The wake-up helpers of ``mrosd.ixm.channel``: writes that no other holder of the descriptor can make block."""

from __future__ import annotations

import fcntl
import os
import secrets
import socket
from pathlib import Path

from mrosd.ixm.channel import drain, drain_socket, is_wake_pipe, is_wake_socket, wake, wake_pipe, wake_socket


def test_a_wake_pipe_made_blocking_and_filled_by_another_holder_never_blocks_a_wake() -> None:
    r, w = wake_pipe()
    try:
        assert fcntl.fcntl(w, 1032) == os.sysconf("SC_PAGE_SIZE")  # F_GETPIPE_SZ: one page pinned at most
        os.set_blocking(w, True)  # what a hostile holder of the shared write end does
        for _ in range(3 * 4096):
            assert wake(w)  # full: a wake-up already pending, not an error, never a block
        drain(r)
        assert wake(w)
        assert os.read(r, 4096) == b"\x01"
        os.close(r)
        assert not wake(w)  # no reader any more: False, no exception
    finally:
        os.close(w)


def test_only_the_write_end_of_an_anonymous_pipe_is_a_wake_pipe(tmp_path: Path) -> None:
    r, w = os.pipe()
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    fr = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    fw = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
    efd = os.eventfd(0)
    try:
        assert is_wake_pipe(w)
        assert not is_wake_pipe(r) and not is_wake_pipe(fw) and not is_wake_pipe(efd) and not is_wake_pipe(-1)
    finally:
        for fd in (r, w, fr, fw, efd):
            os.close(fd)


def test_a_socket_pair_wakes_without_blocking_and_tells_when_the_peer_is_gone() -> None:
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        assert is_wake_socket(theirs, os.geteuid()) and not is_wake_socket(theirs, os.geteuid() + 1)
        theirs.setblocking(True)  # the peer's own description: no effect on our sends
        ours.setblocking(True)
        for _ in range(100_000):
            if not wake_socket(ours):
                break
        assert wake_socket(ours)  # full is pending
        assert drain_socket(theirs)
        theirs.shutdown(socket.SHUT_WR)
        assert not drain_socket(ours)  # end of stream: it will never wake us again
        theirs.close()
        assert not wake_socket(ours)  # EPIPE without SIGPIPE
    finally:
        ours.close()


def test_a_socket_connected_to_someone_else_is_not_a_wake_socket() -> None:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind("\0mrosd-test-third-party-" + secrets.token_hex(6))
    listener.listen(1)
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    conn.connect(listener.getsockname())
    dgram = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        assert not is_wake_socket(conn, os.geteuid())
        assert not is_wake_socket(dgram[0], os.geteuid())
    finally:
        for s in (listener, conn, *dgram):
            s.close()
