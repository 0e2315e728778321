"""Large payloads are neither copied on receive nor on send, and what is shared can never change.

The ownership rule: a ``FrameBuffer`` handed to ``deserialize`` belongs to the message built on it;
large ``uint8[]`` fields are read-only views into it, and ``serialize_parts`` gives them back as they are.
Mutable input (a bytearray, a writable view) is copied, so nothing a caller can still change is aliased.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.msg import get_message_class
from mrosd.msg.runtime import ZERO_COPY_MIN, FrameBuffer, is_immutable
from mrosd.wire.spares import SparePool

Image = get_message_class("sensor_msgs/Image")
PointCloud2 = get_message_class("sensor_msgs/PointCloud2")
PointField = get_message_class("sensor_msgs/PointField")
String = get_message_class("std_msgs/String")


def image(size: int) -> Any:
    return Image(height=1, width=size, encoding="mono8", step=size, data=bytes([size % 251]) * size)


def test_a_frame_buffer_becomes_the_storage_of_large_payloads() -> None:
    body = FrameBuffer(image(ZERO_COPY_MIN).serialize())
    msg = Image.deserialize(body)
    assert isinstance(msg.data, memoryview) and msg.data.readonly
    assert msg.data.obj is body  # a view of the received frame, no copy
    assert msg.encoding == "mono8" and msg.data == bytes([ZERO_COPY_MIN % 251]) * ZERO_COPY_MIN
    with pytest.raises(TypeError):
        msg.data[0] = 1  # type: ignore[index]


def test_mutable_input_is_copied_never_aliased() -> None:
    raw = bytearray(image(ZERO_COPY_MIN).serialize())
    msg = Image.deserialize(raw)
    raw[-1] ^= 0xFF
    assert bytes(msg.data)[-1] == ZERO_COPY_MIN % 251


@pytest.mark.parametrize("size", [0, 3, ZERO_COPY_MIN - 1, ZERO_COPY_MIN, 3 * ZERO_COPY_MIN])
def test_serialize_parts_concatenate_to_serialize(size: int) -> None:
    msg = image(size)
    assert b"".join(msg.serialize_parts()) == msg.serialize()
    cloud = PointCloud2(
        height=1,
        width=size // 4,
        fields=[PointField(name="x", offset=0, datatype=7, count=1)],
        point_step=4,
        row_step=size,
        data=bytes(size),
        is_dense=True,
    )
    assert b"".join(cloud.serialize_parts()) == cloud.serialize()


def test_a_received_payload_is_sent_on_as_the_same_object() -> None:
    received = Image.deserialize(FrameBuffer(image(4 * ZERO_COPY_MIN).serialize()))
    parts = received.serialize_parts()
    assert any(part is received.data for part in parts)  # the echo path never touches the payload's bytes
    assert all(is_immutable(part) for part in parts)
    given_bytes = image(4 * ZERO_COPY_MIN)
    assert any(part is given_bytes.data for part in given_bytes.serialize_parts())


def test_only_pieces_nobody_can_change_count_as_immutable() -> None:
    frame = FrameBuffer(b"abc")
    assert is_immutable(b"abc") and is_immutable(frame) and is_immutable(memoryview(frame).toreadonly())
    assert is_immutable(memoryview(b"abc"))
    assert not is_immutable(bytearray(b"abc"))
    assert not is_immutable(memoryview(bytearray(b"abc")))
    assert not is_immutable(memoryview(bytearray(b"abc")).toreadonly())  # its owner can still write it
    assert not is_immutable(memoryview(frame))  # writable view


def test_types_without_byte_arrays_have_no_parts_method() -> None:
    assert not hasattr(String, "serialize_parts")
    assert hasattr(Image, "serialize_parts") and hasattr(PointCloud2, "serialize_parts")


@settings(deadline=None, max_examples=40)
@given(st.binary(max_size=3 * ZERO_COPY_MIN) | st.integers(0, 3 * ZERO_COPY_MIN).map(bytes), st.text(max_size=20))
def test_frame_buffers_and_bytes_decode_to_equal_messages(data: bytes, encoding: str) -> None:
    body = Image(encoding=encoding, data=data).serialize()
    from_bytes = Image.deserialize(body)
    from_frame = Image.deserialize(FrameBuffer(body))
    assert bytes(from_frame.data) == bytes(from_bytes.data) == data
    assert from_frame.encoding == from_bytes.encoding == encoding
    assert b"".join(from_frame.serialize_parts()) == body


def test_a_spare_pool_refills_a_buffer_only_when_nothing_holds_it() -> None:
    pool = SparePool(max_count=2)
    first = pool.copy(memoryview(b"a" * 100_000))
    assert type(first) is FrameBuffer and first == b"a" * 100_000
    first_id = id(first)
    del first
    again = pool.copy(memoryview(b"b" * 100_000))  # free and of the right size: refilled in place
    assert id(again) == first_id and again == b"b" * 100_000
    # a message decoded from it holds a view: the buffer is not touched while that view lives
    msg = Image.deserialize(Image(height=1, width=100_000, step=100_000, data=b"c" * 100_000).serialize())
    held = pool.copy(memoryview(msg.serialize()))
    decoded = Image.deserialize(held)
    view = decoded.data
    del held, decoded
    other = pool.copy(memoryview(msg.serialize()))
    assert other is not view.obj and bytes(view) == b"c" * 100_000
    assert len(pool) == 2  # no more than ``max_count`` are kept
    held_id = id(view.obj)
    del view  # the last holder of that buffer lets go: it is refilled next
    assert id(pool.copy(memoryview(msg.serialize()))) == held_id
