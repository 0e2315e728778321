"""The requestTopic exchange for shared memory: offers, the publisher's choice, answers; control frames."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import RemoteProtocolError
from mrosd.shm import control
from mrosd.shm.negotiate import (
    PROTOCOL,
    VERSION,
    HostIdentity,
    choose_protocol,
    enabled,
    local_identity,
    parse_answer,
    publisher_answer,
    subscriber_offer,
    trusted_uids,
)
from mrosd.shm.publisher import MIN_SLOTS, RING_BYTES, _grown, slots_for
from mrosd.shm.ring import MAX_SLOTS

HERE = HostIdentity(boot_id="b0", netns="4026531833", uid=1000)
TRUSTED = frozenset({0, 1000})


def test_the_local_identity_is_the_boot_id_netns_and_uid() -> None:
    me = local_identity()
    assert me is not None
    with open("/proc/sys/kernel/random/boot_id") as f:
        assert me.boot_id == f.read().strip()
    assert me.netns.isdigit()


def test_a_same_host_same_uid_offer_is_chosen_before_tcpros() -> None:
    offer = subscriber_offer(HERE)
    chosen = choose_protocol([offer, ["TCPROS"]], HERE, TRUSTED)
    assert chosen is not None and chosen[0] == PROTOCOL
    assert chosen[1] is not None and chosen[1].host == HERE


@pytest.mark.parametrize(
    "other",
    [
        HostIdentity(boot_id="another-kernel", netns=HERE.netns, uid=1000),
        HostIdentity(boot_id="b0", netns="other-netns", uid=1000),
        HostIdentity(boot_id="b0", netns=HERE.netns, uid=1001),
    ],
)
def test_another_host_netns_or_uid_gets_tcpros(other: HostIdentity) -> None:
    assert choose_protocol([subscriber_offer(other), ["TCPROS"]], HERE, TRUSTED) == ("TCPROS", None)


def test_a_trusted_uid_may_share() -> None:
    other = HostIdentity(boot_id="b0", netns=HERE.netns, uid=1001)
    chosen = choose_protocol([subscriber_offer(other), ["TCPROS"]], HERE, TRUSTED | {1001})
    assert chosen is not None and chosen[0] == PROTOCOL


def test_tcpros_first_wins_and_shm_off_or_unknown_identity_gets_tcpros() -> None:
    offer = subscriber_offer(HERE)
    assert choose_protocol([["TCPROS"], offer], HERE, TRUSTED) == ("TCPROS", None)
    assert choose_protocol([offer, ["TCPROS"]], HERE, TRUSTED, shm_available=False) == ("TCPROS", None)
    assert choose_protocol([offer, ["TCPROS"]], None, TRUSTED) == ("TCPROS", None)
    assert choose_protocol([offer], None, TRUSTED) is None
    assert choose_protocol([["UDPROS"]], HERE, TRUSTED) is None


def test_an_offer_of_another_version_is_skipped() -> None:
    offer = subscriber_offer(HERE)
    offer[1] = 99
    assert choose_protocol([offer, ["TCPROS"]], HERE, TRUSTED) == ("TCPROS", None)


@given(st.lists(st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=8), st.lists, max_leaves=8)))
def test_any_protocol_list_is_answered_without_raising(protocols: list[Any]) -> None:
    chosen = choose_protocol(protocols, HERE, TRUSTED)
    assert chosen is None or chosen[0] in ("TCPROS", PROTOCOL)


def test_answer_round_trip() -> None:
    params = publisher_answer("@mrosd-shm-abc", "t" * 32)
    answer = parse_answer(params)
    assert answer is not None and (answer.address, answer.token) == ("@mrosd-shm-abc", "t" * 32)


def test_a_tcpros_answer_is_not_a_shm_answer() -> None:
    assert parse_answer(["TCPROS", "host", 1234]) is None
    assert parse_answer("nonsense") is None


@pytest.mark.parametrize(
    "params",
    [
        [PROTOCOL],
        [PROTOCOL, 1, "@x", "t" * 32],  # the first version (one descriptor per Attached): not ours
        [PROTOCOL, 2, "@x", "t" * 32],  # eventfds both ways, which either side could make blocking: not ours
        [PROTOCOL, 3, "@x", "t" * 32],  # ring layout v2 (slot = message number mod N): no slot a lease can keep
        [PROTOCOL, 5, "@x", "t" * 32],
        [PROTOCOL, True, "@x", "t" * 32],
        [PROTOCOL, VERSION, "/tmp/sock", "t" * 32],
        [PROTOCOL, VERSION, "@" + "x" * 200, "t" * 32],
        [PROTOCOL, VERSION, "@x", "short"],
        [PROTOCOL, VERSION, "@x", 12345678901234567890],
    ],
)
def test_a_bad_shm_answer_is_a_protocol_error(params: list[Any]) -> None:
    with pytest.raises(RemoteProtocolError):
        parse_answer(params)


@given(st.lists(st.none() | st.integers() | st.text(max_size=120) | st.binary(max_size=8), max_size=6))
def test_any_answer_parses_or_is_a_protocol_error(params: list[Any]) -> None:
    try:
        parse_answer([PROTOCOL, *params])
    except RemoteProtocolError:
        pass


def test_environment_switches() -> None:
    assert enabled({}) and enabled({"MROSD_SHM": "1"}) and enabled({"MROSD_SHM": " on "})  # on by default
    assert not enabled({"MROSD_SHM": "0"}) and not enabled({"MROSD_SHM": " Off "})
    assert 1234 in trusted_uids({"MROSD_SHM_TRUSTED_UIDS": "1234, x"})


def test_control_frames_round_trip_and_garbage_is_refused() -> None:
    msg = control.Attach(token="t", header=b"\x01\x02")
    frame = control.encode(msg)
    assert control.decode(frame[4:]) == msg
    with pytest.raises(RemoteProtocolError):
        control.decode(b"\x93garbage")


def test_ring_slots_fill_ring_bytes_within_queue_size_and_the_memory_cap() -> None:
    assert RING_BYTES == 4 << 20 and MIN_SLOTS == 2
    assert slots_for(1, 4096, 1 << 30) == 2  # queue_size + 1, never fewer than MIN_SLOTS
    assert slots_for(10, 4096, 1 << 30) == 11
    assert slots_for(100, 1 << 20, 1 << 30) == 3  # as many 1 MiB slots as fit in RING_BYTES
    assert slots_for(100, 9 << 20, 128 << 20) == 2  # 8 MB images: the backlog queues, the ring pipelines
    assert slots_for(100_000, 64, 1 << 30) == MAX_SLOTS
    assert slots_for(100, 4096, 16384) == 3  # the memory cap wins over RING_BYTES
    assert slots_for(100, 512 << 20, 128 << 20) == 2
    assert _grown(65536, 8 << 20) >= (8 << 20) + (1 << 20)
    assert _grown(65536, 100_000) == 131072


@given(st.binary(max_size=64))
def test_any_control_frame_body_decodes_or_is_a_protocol_error(body: bytes) -> None:
    try:
        msg = control.decode(body)
    except RemoteProtocolError:
        return
    assert isinstance(msg, (control.Attach, control.Attached, control.Refused, control.Ring, control.Progress))
