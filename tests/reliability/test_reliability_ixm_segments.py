"""Hostile IXM clients against the segments: resizing one, sealing it, pre-creating names in /dev/shm.

The daemon and the victims run in their own processes (a SIGBUS there must fail the test, not kill pytest);
the attacker is this process, which never touches its mapping after the attack.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mrosd.ixm.client import IxmClient
from tests.integration.ixm.conftest import start_daemon
from tests.rosenv import Processes, iter_lines_until

READER = textwrap.dedent(
    """
    import sys
    from mrosd.ixm.client import IxmClient
    with IxmClient(sys.argv[1], name="victim") as c:
        k = c.open("/victim")
        print("read", k.read(), flush=True)
        sys.stdin.readline()
        print("read", k.read(), flush=True)
    """
)


def test_a_writer_cannot_resize_or_seal_its_segment_and_neither_the_daemon_nor_readers_die(
    procs: Processes, tmp_path: Path
) -> None:
    path = str(tmp_path / "ixm.sock")
    daemon = start_daemon(procs, path)
    attacker = IxmClient(path, name="attacker")
    key = attacker.open("/victim", "float64", count=512, mode="w")
    key.write([1.0] * 512)
    reader = procs.our_python(["-c", READER, path], stdin=subprocess.PIPE)
    assert next(iter_lines_until(reader, 1, 20.0)).startswith("read [1.0")
    fd = key._state.fd
    outcomes = {}
    for name, action in {
        "shrink": lambda: os.ftruncate(fd, 0),
        "grow": lambda: os.ftruncate(fd, 1 << 30),
        "seal_write": lambda: fcntl.fcntl(fd, fcntl.F_ADD_SEALS, fcntl.F_SEAL_WRITE),
    }.items():
        try:
            action()
            outcomes[name] = "done"
        except OSError as exc:
            outcomes[name] = errno.errorcode[exc.errno or 0]
    # the daemon must hand the key out again (old code: it touched its own mapping here and died of SIGBUS)
    with IxmClient(path, name="second", timeout=5) as second:
        again = second.open("/victim")
        assert again.read()[0] == 1.0
        again.close()
    assert reader.stdin is not None
    reader.stdin.write(b"\n")
    reader.stdin.flush()
    lines = list(iter_lines_until(reader, 1, 20.0))
    assert lines and lines[0].startswith("read [1.0"), f"the reader died: {reader.poll()}"
    assert daemon.poll() is None, "the daemon died"
    assert outcomes == {"shrink": "EPERM", "grow": "EPERM", "seal_write": "EPERM"}
    attacker.close()


def test_segments_have_no_name_in_dev_shm_so_pre_created_names_block_nothing(procs: Processes, tmp_path: Path) -> None:
    path = str(tmp_path / "ixm.sock")
    start_daemon(procs, path)
    before = set(os.listdir("/dev/shm"))
    planted: list[str] = []
    with IxmClient(path, name="squatter") as ixm:
        first = ixm.open("/first", "int32", mode="w")
        name = ixm.list("/first").segments[0].shm_name
        # the old naming (/<prefix><run id>-<n>) is learnt from the listing: plant the next names
        stem, _, n = name.rpartition("-")
        if stem.startswith("/") and n.isdigit():
            for i in range(int(n) + 1, int(n) + 20):
                planted.append(f"/dev/shm{stem}-{i}")
                Path(planted[-1]).write_bytes(b"")
        try:
            keys = [ixm.open(f"/k{i}", "int32", mode="w") for i in range(10)]
            for i, k in enumerate(keys):
                k.write(i)
                assert k.read() == i
            assert set(os.listdir("/dev/shm")) - before == {p.rsplit("/", 1)[1] for p in planted}
        finally:
            for p in planted:
                os.unlink(p)
        first.close()


@pytest.mark.skipif(sys.platform != "linux", reason="memfd seals are Linux-only")
def test_a_segment_is_a_sealed_memfd_readable_only_by_its_daemon_uid(procs: Processes, tmp_path: Path) -> None:
    path = str(tmp_path / "ixm.sock")
    start_daemon(procs, path)
    with IxmClient(path) as ixm:
        key = ixm.open("/sealed", "uint8", count=100, mode="w")
        fd = key._state.fd
        assert os.readlink(f"/proc/self/fd/{fd}").startswith("/memfd:")
        seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
        assert seals & (fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL) == (
            fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL
        )
        assert os.fstat(fd).st_mode & 0o777 == 0o600
        key.close()


WRITER = textwrap.dedent(
    """
    import sys
    from mrosd.ixm.client import IxmClient
    with IxmClient(sys.argv[1], name="writer") as c:
        k = c.open("/locked", "int32", mode="w")
        for i in range(100):
            k.write(i)
        print("wrote", flush=True)
    """
)


def test_a_reader_holding_a_lock_on_its_segment_cannot_stall_writers(procs: Processes, tmp_path: Path) -> None:
    path = str(tmp_path / "ixm.sock")
    start_daemon(procs, path)
    with IxmClient(path, name="staller") as ixm:
        creator = IxmClient(path, name="creator")
        creator.open("/locked", "int32", mode="w")
        key = ixm.open("/locked")
        fcntl.flock(key._state.fd, fcntl.LOCK_EX)  # a read-only descriptor can still take flock
        with contextlib.suppress(OSError):  # and, if it could, a POSIX read lock on the whole file
            fcntl.lockf(key._state.fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        writer = procs.our_python(["-c", WRITER, path])
        lines = list(iter_lines_until(writer, 1, 10.0))
        assert lines == ["wrote"], "a reader's lock stalled the writer"
        assert key.read() == 99
        creator.close()
