"""Fake publishers announce big frames and send a sixteenth of them: a pending frame's buffer must follow the
bytes that arrived, not the length announced.

A pending large frame's buffer grows as its bytes arrive, and a bytearray that grows is filled with zeros
to its new size, so every byte of capacity is resident at once. Before: each time the buffer was full it grew
to sixteen times what had arrived, up to the announced length, so a peer that announced 256 MiB and sent
16 MiB made a mrosd subscriber hold 256 MiB (two such peers: +358 MiB). Now a buffer is at most twice what
arrived (+98 MiB for the two, the peak including a buffer moved while it grew).
"""

from __future__ import annotations

import socket
import struct
import subprocess
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path

import pytest

from mrosd.wire.header import ConnectionHeader, encode_header
from tests.reliability.relnodes import node_env, start_master
from tests.reliability.test_reliability_frames_claims import VICTIM, FakePublishers, String, _read_exact, _rss_fields
from tests.rosenv import Processes, iter_lines_until

MiB = 1024 * 1024
FAKES = 2
#: what each fake announces, and what it sends of it: just past a sixteenth, where the old rule took the
#: announced size (its buffer grew 64 KiB -> 1 MiB -> 16 MiB -> 256 MiB, each time it was full)
CLAIMED = 256 * MiB
SENT = 16 * MiB + 64 * 1024


class PartialPublishers(FakePublishers):
    """Fakes that send a header, one honest frame, then ``SENT`` bytes of a ``CLAIMED``-byte frame."""

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            self.conns.append(conn)
            conn.settimeout(10)
            length = struct.unpack("<I", _read_exact(conn, 4))[0]
            _read_exact(conn, length)  # the subscriber's header
            self.served += 1
            reply = encode_header(
                ConnectionHeader(
                    callerid=f"/fake{self.served}",
                    md5sum=String._md5sum,
                    type=String._type,
                    message_definition=String._full_text,
                    latching="0",
                )
            )
            hello = String(data=f"hello{self.served}").serialize()
            conn.sendall(reply + struct.pack("<I", len(hello)) + hello + struct.pack("<I", CLAIMED))
            try:
                conn.sendall(bytes(SENT))
            except OSError:
                return


@pytest.fixture
def fakes() -> Iterator[PartialPublishers]:
    fake = PartialPublishers()
    yield fake
    fake.close()


def test_a_partly_sent_big_frame_costs_what_arrived(procs: Processes, tmp_path: Path, fakes: PartialPublishers) -> None:
    _, master = start_master(procs)
    victim = procs.our_python(["-c", VICTIM], node_env(master, tmp_path), stderr=subprocess.DEVNULL)
    lines = iter_lines_until(victim, 1 + FAKES, 60)
    assert next(lines) == "ready"
    baseline = _rss_fields(victim.pid)["VmRSS"]
    with xmlrpc.client.ServerProxy(master) as proxy:
        for index in range(1, FAKES + 1):
            code, msg, _ = proxy.registerPublisher(f"/fake{index}", "/victim", String._type, fakes.uri(index))
            assert code == 1, msg
            assert next(lines) == f"hello{index}"
    # what arrived is resident in any case: wait for it, then give the last reads a moment to land
    deadline = time.monotonic() + 20
    while _rss_fields(victim.pid)["VmHWM"] - baseline < FAKES * SENT * 0.9 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    growth = _rss_fields(victim.pid)["VmHWM"] - baseline
    print(f"victim's peak RSS +{growth / MiB:.0f} MiB for {FAKES} x {SENT / MiB:.0f} MiB sent of {CLAIMED // MiB} MiB")
    assert growth >= FAKES * SENT * 0.9, "the data never arrived"
    assert growth < 4 * FAKES * SENT, f"+{growth / MiB:.0f} MiB for {FAKES * SENT / MiB:.0f} MiB received"
    assert victim.poll() is None, "the victim died"
    for conn in fakes.conns:
        conn.shutdown(socket.SHUT_RDWR)
