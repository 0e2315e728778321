"""The bridge's key expressions, renaming and globs (pure; the exact strings are zenoh-plugin-ros1's)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.fleet.keys import (
    FleetKeyError,
    Item,
    ItemKind,
    NameFilter,
    RenameRule,
    data_key,
    discovery_key,
    discovery_subscription,
    parse_data_key,
    parse_discovery_key,
)
from mrosd.msg import get_message_class

STRING_MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"
IMAGE_MD5 = "060021388200f6f0f447d0fcd9c64743"
# hex::encode(b"std_msgs/String") and hex::encode(b"sensor_msgs/Image"), as the bridge's make_zenoh_key computes
STRING_HEX = "7374645f6d7367732f537472696e67"
IMAGE_HEX = "73656e736f725f6d7367732f496d616765"


def test_string_keys_are_the_bridges() -> None:
    assert data_key("std_msgs/String", STRING_MD5, "*", "/chatter") == f"{STRING_HEX}/{STRING_MD5}/*/chatter"
    assert (
        discovery_key(ItemKind.PUBLISHER, "std_msgs/String", STRING_MD5, "*", "/chatter")
        == f"ros1_discovery_info/*/pub/{STRING_HEX}/{STRING_MD5}/*/chatter"
    )


def test_image_keys_are_the_bridges() -> None:
    # the bridge trims leading and trailing '/' only; inner ones stay as key chunks
    assert (
        data_key("sensor_msgs/Image", IMAGE_MD5, "robot1", "/camera/image_raw/")
        == f"{IMAGE_HEX}/{IMAGE_MD5}/robot1/camera/image_raw"
    )
    for kind in ItemKind:
        key = discovery_key(kind, "sensor_msgs/Image", IMAGE_MD5, "*", "/camera/image_raw")
        assert key == f"ros1_discovery_info/*/{kind.value}/{IMAGE_HEX}/{IMAGE_MD5}/*/camera/image_raw"
        assert parse_discovery_key(key) == Item(kind, "sensor_msgs/Image", IMAGE_MD5, "*", "/camera/image_raw")


def test_discovery_subscription_matches_the_bridges_listener() -> None:
    # the bridge listens with topic "*/**" and its BRIDGE_NAMESPACE
    assert discovery_subscription() == "ros1_discovery_info/*/*/*/*/*/*/**"
    assert discovery_subscription("robot1") == "ros1_discovery_info/*/*/*/*/robot1/*/**"


def test_payload_is_the_body_without_the_frame_length() -> None:
    string = get_message_class("std_msgs/String")(data="hello")
    assert string.serialize() == b"\x05\x00\x00\x00hello"  # the string's own length stays
    image_cls = get_message_class("sensor_msgs/Image")
    img = image_cls(height=1, width=2, encoding="mono8", is_bigendian=0, step=2, data=b"\x01\x02")
    img.header.frame_id = "cam"
    expected = (
        struct.pack("<III", 0, 0, 0)
        + struct.pack("<I", 3)
        + b"cam"
        + struct.pack("<II", 1, 2)
        + struct.pack("<I", 5)
        + b"mono8"
        + b"\x00"
        + struct.pack("<I", 2)
        + struct.pack("<I", 2)
        + b"\x01\x02"
    )
    assert img.serialize() == expected


@pytest.mark.parametrize(
    "key",
    [
        "ros1_discovery_info/*/pub",
        "other/*/pub/7374645f6d7367732f537472696e67/992ce8a1687cec8c8bd883ec73ca41d1/*/chatter",
        f"ros1_discovery_info/*/bogus/{STRING_HEX}/{STRING_MD5}/*/chatter",
        f"ros1_discovery_info/*/pub/zz/{STRING_MD5}/*/chatter",
        f"ros1_discovery_info/*/pub/ff/{STRING_MD5}/*/chatter",
        f"ros1_discovery_info/*/pub/{b'no_slash'.hex()}/{STRING_MD5}/*/chatter",
        f"ros1_discovery_info/*/pub/{STRING_HEX}/short/*/chatter",
        f"ros1_discovery_info/*/pub/{STRING_HEX}/{STRING_MD5}/a$b/chatter",
        f"ros1_discovery_info/*/pub/{STRING_HEX}/{STRING_MD5}/*/9bad",
        f"ros1_discovery_info/*/pub/{STRING_HEX}/{STRING_MD5}/*/a//b",
        f"ros1_discovery_info/*/pub/{STRING_HEX}/{STRING_MD5}/*/",
    ],
)
def test_malformed_discovery_keys_are_refused(key: str) -> None:
    with pytest.raises(FleetKeyError):
        parse_discovery_key(key)


_seg = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,8}", fullmatch=True)
_topic = st.lists(_seg, min_size=1, max_size=4).map(lambda s: "/" + "/".join(s))
_type = st.tuples(_seg, _seg).map(lambda t: f"{t[0]}/{t[1]}")
_md5 = st.from_regex(r"[0-9a-f]{32}", fullmatch=True)
_ns = st.one_of(st.just("*"), st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,10}", fullmatch=True))


@given(st.sampled_from(list(ItemKind)), _type, _md5, _ns, _topic)
def test_discovery_keys_round_trip(kind: ItemKind, msg_type: str, md5: str, ns: str, topic: str) -> None:
    item = Item(kind, msg_type, md5, ns, topic)
    assert parse_discovery_key(item.discovery_key) == item
    assert parse_data_key(item.data_key) == (msg_type, md5, ns, topic)


@given(st.text(max_size=120))
def test_any_text_parses_or_raises_fleet_key_error(key: str) -> None:
    try:
        item = parse_discovery_key(key)
    except FleetKeyError:
        return
    assert item.discovery_key == key


@given(_seg, _topic)
def test_renaming_round_trips(robot: str, topic: str) -> None:
    rule = RenameRule()
    local = rule.local_name(robot, topic)
    assert local == f"/{robot}{topic}"
    assert rule.remote_name(local, {robot}) == (robot, topic)


def test_renaming_rules() -> None:
    # an item under ``*`` keeps no local name unless the configuration maps it (issue 31, case 3)
    assert RenameRule().local_name("*", "/chatter") is None
    assert RenameRule(prefix="").local_name("*", "/chatter") == "/chatter"
    assert RenameRule(wildcard_robot="legacy").local_name("*", "/chatter") == "/legacy/chatter"
    assert RenameRule(prefix="").local_name("robot1", "/chatter") == "/chatter"
    assert RenameRule(prefix="/fleet/{robot}").local_name("r2", "/odom") == "/fleet/r2/odom"
    assert RenameRule().remote_name("/robot10/x", {"robot1"}) is None
    assert RenameRule().remote_name("/robot1", {"robot1"}) is None


def test_name_filter_globs() -> None:
    f = NameFilter(include=("/chatter", "/camera/**", "/robot*/odom"), exclude=("/camera/secret/**",))
    assert "/chatter" in f
    assert "/chatter2" not in f
    assert "/camera/image_raw" in f and "/camera/a/b" in f
    assert "/camera/secret/x" not in f
    assert "/robot7/odom" in f and "/robot7/x/odom" not in f
    assert "/anything" not in NameFilter()
