"""What the daemon holds for clients: sealed segments, their descriptors, the default caps; the socket directory."""

from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import IxmError
from mrosd.ixm.layout import SegmentLayout
from mrosd.ixm.registry import SegmentInfo
from mrosd.ixm.resources import MAX_WAKE_READERS, WAKE_SLOTS_PER_UID, Limits, NoticePage, Segment, wake_slot_refusal
from mrosd.ixm.rundir import prepare_socket_dir
from mrosd.ixm.types import resolve_type


def test_default_caps_keep_within_three_quarters_of_the_fd_limit_and_given_values_win() -> None:
    small = Limits.for_fd_limit(512)
    assert small.max_clients + 2 * small.max_keys <= 512 * 3 // 4
    assert small.max_clients_per_uid < small.max_clients and small.max_keys_per_uid < small.max_keys
    big = Limits.for_fd_limit(1 << 20)
    assert (big.max_clients, big.max_clients_per_uid, big.max_keys, big.max_keys_per_uid) == (4096, 1024, 65536, 16384)
    assert Limits.for_fd_limit(512, max_clients=7, max_keys=None).max_clients == 7


def test_a_segment_is_sealed_initialised_and_reopened_per_client() -> None:
    kind = resolve_type("float64", 3, None)
    info = SegmentInfo(key="/k", shm_name="memfd:mrosd-ixm-test-1", type=kind, creator_uid=0)
    seg = Segment(info)
    try:
        rw, ro = seg.open_fd(write=True), seg.open_fd(write=False)
        try:
            assert os.pread(ro, 4, 0) == b"IXM1"
            assert os.fstat(rw).st_size == SegmentLayout.segment_size(24)
            assert os.fstat(rw).st_mode & 0o777 == 0o600
            for fd, size in ((rw, 0), (rw, 1 << 20)):
                with pytest.raises(OSError) as exc:
                    os.ftruncate(fd, size)
                assert exc.value.errno == errno.EPERM
            with pytest.raises(OSError):
                fcntl.fcntl(rw, fcntl.F_ADD_SEALS, fcntl.F_SEAL_WRITE)
            with pytest.raises(OSError):
                os.write(ro, b"x")
            # each client has its own open file description: writers' flocks exclude each other
            other = seg.open_fd(write=True)
            fcntl.flock(rw, fcntl.LOCK_EX)
            with pytest.raises(BlockingIOError):
                fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
            os.close(other)
        finally:
            os.close(rw)
            os.close(ro)
    finally:
        seg.close()


def test_a_notice_page_is_written_by_the_daemon_and_read_only_for_the_client() -> None:
    page = NoticePage("mrosd-ixm-notice-test")
    try:
        page.count[0] = 5
        assert int.from_bytes(os.pread(page.client_fd, 8, 0), "little") == 5
        with pytest.raises(OSError):
            os.write(page.client_fd, b"x")
    finally:
        os.close(page.client_fd)
        page.close()


def test_a_missing_socket_directory_is_created_0700_and_an_existing_safe_one_is_kept(tmp_path: Path) -> None:
    new = tmp_path / "run"
    prepare_socket_dir(str(new))
    assert new.stat().st_mode & 0o777 == 0o700
    os.chmod(new, 0o755)
    prepare_socket_dir(str(new))
    assert new.stat().st_mode & 0o777 == 0o755


def test_an_unsafe_socket_directory_is_refused_in_one_line_naming_it_and_the_fix(tmp_path: Path) -> None:
    target = tmp_path / "real"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    with pytest.raises(IxmError, match="is a symlink") as exc:
        prepare_socket_dir(str(link))
    assert str(link) in str(exc.value) and "\n" not in str(exc.value)
    os.chmod(target, 0o777)
    with pytest.raises(IxmError, match=r"writable by group or others.*chmod go-w"):
        prepare_socket_dir(str(target))
    os.chmod(target, 0o700)
    with pytest.raises(IxmError, match=r"owned by uid \d+, not by uid \d+ or root.*chown \d+"):
        prepare_socket_dir(str(target), euid=4242) if os.geteuid() != 0 else _owned_by_other(target)
    file = tmp_path / "file"
    file.write_text("")
    with pytest.raises(IxmError, match="cannot use the IXM socket directory"):
        prepare_socket_dir(str(file))


def _owned_by_other(path: Path) -> None:
    os.chown(path, 4242, 4242)
    try:
        prepare_socket_dir(str(path), euid=1234)
    finally:
        os.chown(path, 0, 0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([0, 1000, 1001, 65534, 4242, 7]), max_size=600))
def test_no_uid_takes_more_than_its_share_of_woken_reader_slots(attempts: list[int]) -> None:
    """Opens in any order by a few uids: each uid keeps at most its share, the key at most its slots, and a
    uid below its share is refused only when the key is full (five uids at their share)."""
    held: list[int] = []
    for uid in attempts:
        refusal = wake_slot_refusal("/k", held, uid)
        mine = held.count(uid)
        if refusal:
            assert mine >= WAKE_SLOTS_PER_UID or len(held) >= MAX_WAKE_READERS
        else:
            held.append(uid)
        assert held.count(uid) <= WAKE_SLOTS_PER_UID and len(held) <= MAX_WAKE_READERS
    assert len({u for u in held}) >= 5 or len(held) < MAX_WAKE_READERS


def test_a_refused_woken_reader_is_told_which_limit() -> None:
    full_share = [65534] * WAKE_SLOTS_PER_UID
    assert "its share (63 of 253)" in wake_slot_refusal("/k", full_share, 65534)
    assert wake_slot_refusal("/k", full_share, 1000) == ""
    assert "253 woken readers" in wake_slot_refusal("/k", [1, 2, 3, 4, 5] * 51, 6)
