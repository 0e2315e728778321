"""rmw_zenoh's keys and tokens: known answers from its source and round trips."""

from __future__ import annotations

import pytest

from mrosd.errors import RemoteProtocolError
from mrosd.ros2.attachment import decode_attachment, encode_attachment, gid_of
from mrosd.ros2.keys import (
    DEFAULT_QOS,
    EntityKind,
    LivelinessToken,
    Qos,
    data_key,
    dds_type_name,
    decode_qos,
    encode_qos,
    parse_token,
    ros2_type_of_dds,
)

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_the_data_key_of_chatter_is_rmw_zenohs() -> None:
    assert data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )
    assert data_key(7, "/robot/scan/", "sensor_msgs/msg/LaserScan", "h") == (
        "7/robot/scan/sensor_msgs::msg::dds_::LaserScan_/h"
    )


def test_dds_type_names_go_both_ways() -> None:
    assert dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert ros2_type_of_dds("std_msgs::msg::dds_::String_") == "std_msgs/msg/String"
    with pytest.raises(RemoteProtocolError):
        ros2_type_of_dds("std_msgs/String")


def test_the_default_qos_is_all_empty_and_a_reliable_volatile_depth_10_publisher_says_only_its_depth() -> None:
    assert encode_qos(DEFAULT_QOS) == "::,:,:,:,,"
    assert encode_qos(Qos(depth=10)) == "::,10:,:,:,,"
    assert encode_qos(Qos(durability=1, depth=1)) == ":1:,1:,:,:,,"
    assert encode_qos(Qos(reliability=2, history=2)) == "2::2,:,:,:,,"


@pytest.mark.parametrize(
    "qos",
    [DEFAULT_QOS, Qos(depth=10), Qos(reliability=2, durability=1, history=2, depth=1, deadline=(1, 5), lease=(0, 9))],
)
def test_qos_round_trips(qos: Qos) -> None:
    assert decode_qos(encode_qos(qos)) == qos


def test_a_publisher_token_has_the_chunks_rmw_zenoh_writes_and_parses_back() -> None:
    tok = LivelinessToken(
        domain_id=0,
        zid="aabbccdd",
        nid="0",
        id="3",
        kind=EntityKind.PUBLISHER,
        enclave="/",
        namespace="/",
        node="talker",
        topic="/chatter",
        type_name="std_msgs::msg::dds_::String_",
        type_hash=STRING_HASH,
        qos=Qos(depth=7),
    )
    assert tok.key() == (
        f"@ros2_lv/0/aabbccdd/0/3/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
    )
    assert parse_token(tok.key()) == tok


def test_a_node_token_in_a_namespace_round_trips() -> None:
    tok = LivelinessToken(
        domain_id=3, zid="z", nid="1", id="1", kind=EntityKind.NODE, enclave="/", namespace="/a/b", node="n"
    )
    assert tok.key() == "@ros2_lv/3/z/1/1/NN/%/%a%b/n"
    assert parse_token(tok.key()) == tok


@pytest.mark.parametrize(
    "bad",
    [
        "@ros2_lv/0/z/1/1/NN/%/%",  # too short
        "@ros2_lv/0/z/1/1/NN/%//n",  # empty chunk
        "@other/0/z/1/1/NN/%/%/n",
        "@ros2_lv/0/z/1/1/XX/%/%/n",
        "@ros2_lv/x/z/1/1/NN/%/%/n",
        "@ros2_lv/0/z/1/1/MP/%/%/n/%t",  # endpoint without type, hash, qos
        "@ros2_lv/0/z/1/1/MP/%/%/n/%t/T/H/1:2",  # short qos
        "@ros2_lv/0/z/1/1/MP/%/%/n/%t/T/H/a::,:,:,:,,",  # not a number
        "@ros2_lv/0/z/1/1/NN/%/%/" + "n" * 5000,
    ],
)
def test_bad_tokens_are_one_remote_protocol_error(bad: str) -> None:
    with pytest.raises(RemoteProtocolError):
        parse_token(bad)


def test_the_attachment_is_zenohs_serialization_of_seq_stamp_and_gid() -> None:
    zenoh_ext = pytest.importorskip("zenoh.ext")
    gid = gid_of("@ros2_lv/0/z/1/1/MP/%/%/n/%t/T/H/::,:,:,:,,")
    assert len(gid) == 16
    ours = encode_attachment(5, 1_700_000_000_123_456_789, gid)
    theirs = zenoh_ext.z_serialize((zenoh_ext.Int64(5), zenoh_ext.Int64(1_700_000_000_123_456_789), gid))
    assert ours == theirs.to_bytes()
    back = decode_attachment(ours)
    assert (back.sequence_number, back.source_timestamp, back.gid) == (5, 1_700_000_000_123_456_789, gid)
    with pytest.raises(RemoteProtocolError):
        decode_attachment(ours[:-1])
    with pytest.raises(RemoteProtocolError):
        decode_attachment(ours[:16] + b"\x0f" + ours[17:])


def test_the_cores_import_no_asyncio_zenoh_or_sockets() -> None:
    import subprocess
    import sys

    code = (
        "import sys, mrosd.ros2.keys, mrosd.ros2.attachment, mrosd.ros2.types\n"
        "print(sorted(m for m in ('asyncio', 'zenoh', 'aiohttp', 'socket', 'threading') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.strip() == "[]"
