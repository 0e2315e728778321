"""IXM across real processes: write here, read there, wake-ups, death releases keys, restarts clean up."""

from __future__ import annotations

import os
import signal
import subprocess
import textwrap
from pathlib import Path

import pytest

from mrosd.errors import IxmError
from mrosd.ixm import IxmClient
from tests.integration.ixm.conftest import ShmGuard, own_segments, python_child, start_daemon, until, wait_line
from tests.rosenv import Processes


def reader_script(sock: str, n: int) -> str:
    return textwrap.dedent(
        f"""
        from mrosd.ixm import IxmClient
        with IxmClient({sock!r}, name="reader") as ixm:
            key = ixm.open("/arm/joints", "float64", count=3, mode="r")
            print("ready", flush=True)
            for _ in range({n}):
                print(key.wait(10.0), flush=True)
        """
    )


def test_a_value_written_in_one_process_is_read_in_another(ixm_socket: str, procs: Processes) -> None:
    with IxmClient(ixm_socket) as ixm:
        key = ixm.open("/pose", "float64", count=2, mode="w")
        key.write([1.5, -2.0])
        child = python_child(
            procs,
            f"from mrosd.ixm import IxmClient\nwith IxmClient({ixm_socket!r}) as c: print(c.open('/pose').read())",
        )
        out, _ = child.communicate(timeout=20)
        assert out.decode().strip() == "[1.5, -2.0]"


def test_a_waiting_reader_in_another_process_is_woken_by_each_write(ixm_socket: str, procs: Processes) -> None:
    child = python_child(procs, reader_script(ixm_socket, 3))
    wait_line(child, "ready")
    assert child.stdout is not None
    with IxmClient(ixm_socket) as ixm:
        key = ixm.open("/arm/joints", "float64", count=3, mode="w")
        for i in range(3):
            key.write([float(i)] * 3)
            assert child.stdout.readline().decode().strip() == str([float(i)] * 3)
    assert child.wait(10) == 0


def test_a_killed_process_releases_its_keys_and_the_segment_is_freed(ixm_socket: str, procs: Processes) -> None:
    before = own_segments(ixm_socket)
    child = python_child(
        procs,
        textwrap.dedent(
            f"""
            import time
            from mrosd.ixm import IxmClient
            c = IxmClient({ixm_socket!r}, name="victim")
            c.open("/victim", "int64", mode="w").write(7)
            print("ready", flush=True)
            time.sleep(60)
            """
        ),
    )
    wait_line(child, "ready")
    with IxmClient(ixm_socket) as ixm:
        assert [s.key for s in ixm.list().segments] == ["/victim"]
        assert len(own_segments(ixm_socket) - before) == 1
        os.killpg(child.pid, signal.SIGKILL)
        child.wait(10)
        until(lambda: not ixm.list().segments)
        assert [p.pid for p in ixm.list().processes] == [os.getpid()]
    assert own_segments(ixm_socket) - before == set()


def test_closing_the_last_holder_unlinks_the_segment(ixm_socket: str) -> None:
    before = own_segments(ixm_socket)
    with IxmClient(ixm_socket) as a, IxmClient(ixm_socket) as b:
        w = a.open("/k", "uint32", mode="w")
        r = b.open("/k", "uint32")
        assert len(own_segments(ixm_socket) - before) == 1
        w.close()
        assert len(own_segments(ixm_socket) - before) == 1
        r.close()
        assert own_segments(ixm_socket) - before == set()


def test_a_crashed_daemon_leaves_no_segment_once_its_clients_let_go_and_restarts_clean(
    shm_guard: ShmGuard, procs: Processes, tmp_path: Path
) -> None:
    sock = str(tmp_path / "ixm.sock")
    daemon = start_daemon(procs, sock)
    before = own_segments(sock)
    ixm = IxmClient(sock)
    ixm.open("/left/behind", "float64", mode="w").write(1.0)
    stale = own_segments(sock) - before
    assert len(stale) == 1
    os.killpg(daemon.pid, signal.SIGKILL)  # no chance to clean up
    daemon.wait(10)
    assert stale <= own_segments(sock)  # the client still maps it: its memory stays valid
    ixm.close()
    assert not (stale & own_segments(sock))  # a memfd goes with its last holder: nothing to sweep
    start_daemon(procs, sock)
    with IxmClient(sock) as again:
        assert again.list().segments == []


def test_a_second_daemon_on_a_live_socket_refuses_to_start(ixm_socket: str, procs: Processes) -> None:
    proc = procs.our_python(["-m", "mrosd.ixm", "--socket", ixm_socket], stderr=subprocess.PIPE)
    assert proc.wait(20) == 1
    assert proc.stderr is not None
    assert b"already serving" in proc.stderr.read()


def test_a_reader_cannot_write_through_the_api_or_its_mapping(ixm_socket: str) -> None:
    with IxmClient(ixm_socket) as ixm:
        ixm.open("/ro", "float64", count=2, mode="w").write([1.0, 2.0])
        with IxmClient(ixm_socket) as other:
            reader = other.open("/ro")
            with pytest.raises(IxmError, match="reading only"):
                reader.write([3.0, 4.0])
            with pytest.raises(TypeError):
                reader._state.map[70] = 1  # the mapping itself is PROT_READ
            import mmap

            with pytest.raises(PermissionError):
                mmap.mmap(reader._state.fd, 0, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
            assert reader.read() == [1.0, 2.0]


def test_a_client_sending_garbage_is_disconnected_and_the_daemon_keeps_serving(ixm_socket: str) -> None:
    import socket

    with IxmClient(ixm_socket) as ixm:
        ixm.open("/alive", "int8", mode="w").write(5)
        bad = socket.socket(socket.AF_UNIX)
        bad.settimeout(5)
        bad.connect(ixm_socket)
        bad.sendall(b"\xff\xff\xff\x7fgarbage")
        assert bad.recv(10) == b""  # the daemon closed only this connection
        bad.close()
        with IxmClient(ixm_socket) as again:
            assert again.open("/alive").read() == 5


def test_a_type_mismatch_and_a_missing_daemon_are_clear_errors(ixm_socket: str, tmp_path: Path) -> None:
    with IxmClient(ixm_socket) as ixm:
        ixm.open("/t", "float64", mode="w")
        with IxmClient(ixm_socket) as other, pytest.raises(IxmError, match=r"holds float64.*asked for int32"):
            other.open("/t", "int32")
    with pytest.raises(IxmError, match="cannot reach the IXM daemon"):
        IxmClient(str(tmp_path / "nobody.sock"))


def test_a_stopped_reader_never_stalls_the_writer_and_then_sees_the_latest_value(
    ixm_socket: str, procs: Processes
) -> None:
    child = python_child(
        procs,
        textwrap.dedent(
            f"""
            import sys
            from mrosd.ixm import IxmClient
            with IxmClient({ixm_socket!r}) as ixm:
                key = ixm.open("/ctl", "int64", mode="r")
                print("ready", flush=True)
                sys.stdin.readline()
                print(key.wait(10.0), flush=True)
            """
        ),
    )
    wait_line(child, "ready")
    os.kill(child.pid, signal.SIGSTOP)  # a reader that never runs: its eventfd fills, nobody reads
    try:
        with IxmClient(ixm_socket) as ixm:
            key = ixm.open("/ctl", "int64", mode="w")
            for i in range(50_000):
                key.write(i)
            os.kill(child.pid, signal.SIGCONT)
            assert child.stdin is not None and child.stdout is not None
            child.stdin.write(b"go\n")
            child.stdin.flush()
            assert child.stdout.readline().decode().strip() == "49999"
    finally:
        os.kill(child.pid, signal.SIGCONT)
    assert child.wait(10) == 0


def test_a_ping_pong_between_processes_sees_every_value_once_with_spin_then_block(
    ixm_socket: str, procs: Processes
) -> None:
    """Each wait spins on the counter before blocking (mrosd.spin); in a tight exchange most wake-ups are
    caught spinning. No value may be missed or seen twice (a torn counter once made a reader see a value
    twice), and the eventfd signals left behind by caught writes must not cause lost or spurious waits."""
    n = 2000
    child = python_child(
        procs,
        textwrap.dedent(
            f"""
            from mrosd.ixm import IxmClient
            with IxmClient({ixm_socket!r}, name="echo") as ixm:
                value = ixm.open("/pp/value", "int64", mode="r")
                ack = ixm.open("/pp/ack", "int64", mode="w")
                print("ready", flush=True)
                for expected in range({n}):
                    got = value.wait(10.0)
                    if got != expected:
                        print("wrong", got, "for", expected, flush=True)
                        raise SystemExit(1)
                    ack.write(got)
                print("done", flush=True)
            """
        ),
    )
    wait_line(child, "ready")
    with IxmClient(ixm_socket, name="driver") as ixm:
        value = ixm.open("/pp/value", "int64", mode="w")
        ack = ixm.open("/pp/ack", "int64", mode="r")
        for i in range(n):
            value.write(i)
            assert ack.wait(10.0) == i
    wait_line(child, "done")
    assert child.wait(10) == 0


def test_a_read_write_client_is_handed_the_other_readers_eventfds_but_never_its_own(ixm_socket: str) -> None:
    with IxmClient(ixm_socket, name="both") as mine, IxmClient(ixm_socket, name="other") as theirs:
        key = mine.open("/rw", "int64", mode="rw")
        assert key._state.targets == []  # the only reader is this client itself
        other = theirs.open("/rw", mode="r")
        key.write(1)  # the generation changed: the writer takes its new list before signalling
        assert len(key._state.targets) == 1
        assert other.wait(5.0) == 1
