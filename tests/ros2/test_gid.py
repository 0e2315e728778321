"""The GID of an entity is rmw_zenoh's: XXH3-128 of its liveliness key, low 64 bits then high 64, little-endian."""

from __future__ import annotations

from mrosd.ros2.attachment import GID_SIZE, gid_of


def test_the_gid_of_the_empty_key_is_xxh3_128s_published_answer_in_rmw_zenohs_byte_order() -> None:
    # xxHash's sanity table: XXH3_128bits("") = {low64 0x6001C324468D497F, high64 0x99AA06D3014798D8}
    low, high = 0x6001C324468D497F, 0x99AA06D3014798D8
    assert gid_of("") == low.to_bytes(8, "little") + high.to_bytes(8, "little")


def test_gids_are_sixteen_bytes_stable_and_differ_per_key() -> None:
    a = gid_of("@ros2_lv/0/z/0/1/MP/%/%/n/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,:,:,:,,")
    b = gid_of("@ros2_lv/0/z/0/2/MP/%/%/n/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,:,:,:,,")
    assert len(a) == GID_SIZE and a != b
    assert a == gid_of("@ros2_lv/0/z/0/1/MP/%/%/n/%chatter/std_msgs::msg::dds_::String_/RIHS01_x/::,:,:,:,,")
