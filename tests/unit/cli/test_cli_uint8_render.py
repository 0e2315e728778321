"""The fast uint8[] renderer agrees byte for byte with rostopic's ``str(list(data))`` wherever it is used.

``uint8_pieces`` renders an array a slice at a time (``_SLICE`` bytes), reusing one cell buffer for the
whole slices and filling it with translate passes, so these tests cover what that could get wrong: odd and
even lengths, the empty array, lengths around the slice size (and, with a tiny slice, many slices of
arbitrary bytes), a size change between frames, the same size with new data, views and bytearrays as input,
several big arrays in one message (each spliced in as its own pieces), big arrays inside arrays of messages,
and threads rendering at the same time.
"""

from __future__ import annotations

import os
import threading
from typing import ClassVar
from unittest import mock

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mros_cli import output
from mros_cli.output import TextRenderer, uint8_bytes, uint8_pieces, uint8_text


class Blob(msgspec.Struct):
    _type: ClassVar[str] = "test/Blob"
    _field_types: ClassVar[tuple[str, ...]] = ("string", "uint8[]")
    name: str = ""
    data: bytes = b""


class Frames(msgspec.Struct):
    _type: ClassVar[str] = "test/Frames"
    _field_types: ClassVar[tuple[str, ...]] = ("test/Blob[]", "uint8[]", "test/Blob", "uint8[4]")
    blobs: list[Blob] = msgspec.field(default_factory=list)
    raw: bytes = b""
    inner: Blob = msgspec.field(default_factory=Blob)
    fixed: bytes = b"\0\0\0\0"


def reference(data: bytes) -> bytes:
    """What rostopic (genpy's strify_message) prints for a uint8[] value."""
    return str(list(data)).encode()


@pytest.mark.parametrize("size", [0, 1, 2, 3, 4, 5, 9, 10, 99, 100, 255, 4095, 4096, 4097, 10_001, 65_537])
def test_uint8_bytes_matches_rostopic_for_odd_even_and_boundary_lengths(size: int) -> None:
    data = os.urandom(size)
    assert uint8_bytes(data) == reference(data)
    assert uint8_bytes(memoryview(data)) == reference(data)
    assert uint8_bytes(bytearray(data)) == reference(data)


@pytest.mark.parametrize("size", [32767, 32768, 32769, 65536, 65537, 3 * 32768 + 5, 1 << 20])
def test_arrays_of_one_slice_and_of_many_render_exactly_in_pieces(size: int) -> None:
    assert output._SLICE == 32768  # the sizes above sit around it
    data = os.urandom(size)
    pieces = uint8_pieces(memoryview(data))
    assert b"".join(pieces) == reference(data)
    assert len(pieces) == (1 if size <= output._SLICE else 1 + -(-size // output._SLICE))


@given(st.binary(max_size=2000), st.integers(min_value=1, max_value=40))
def test_any_bytes_in_any_number_of_slices_render_as_str_of_the_list(data: bytes, slice_size: int) -> None:
    with mock.patch.object(output, "_SLICE", slice_size):
        expected = str(list(data))
        assert b"".join(uint8_pieces(data)) == expected.encode()
        assert b"".join(uint8_pieces(memoryview(bytearray(data)))) == expected.encode()
        assert uint8_bytes(data) == expected.encode()
        assert uint8_text(data) == expected


def test_every_byte_value_renders_as_its_decimal() -> None:
    data = bytes(range(256)) + bytes(range(255, -1, -1))
    assert uint8_text(data) == str(list(data))


def test_the_empty_array_is_two_brackets() -> None:
    assert uint8_bytes(b"") == b"[]"
    assert uint8_bytes(memoryview(b"")) == b"[]"


def test_the_reused_buffer_never_leaks_digits_between_frames_of_the_same_or_another_size() -> None:
    big, small = bytes([255]) * 5000, bytes([1]) * 5000
    assert uint8_bytes(big) == reference(big)
    assert uint8_bytes(small) == reference(small)
    shorter = bytes([7]) * 4999
    assert uint8_bytes(shorter) == reference(shorter)
    assert uint8_bytes(big) == reference(big)


@given(st.lists(st.binary(max_size=300), max_size=6))
def test_a_sequence_of_frames_of_varying_sizes_renders_each_exactly(frames: list[bytes]) -> None:
    for data in frames:
        assert uint8_bytes(data) == reference(data)


def test_threads_rendering_at_once_each_get_their_own_exact_text() -> None:
    inputs = [os.urandom(20_000) for _ in range(8)]
    results: dict[int, bytes] = {}

    def work(i: int) -> None:
        for _ in range(5):
            results[i] = uint8_bytes(inputs[i])
            assert results[i] == reference(inputs[i])

    threads = [threading.Thread(target=work, args=(i,)) for i in range(len(inputs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert all(results[i] == reference(inputs[i]) for i in range(len(inputs)))


def expected_frames(msg: Frames) -> str:
    lines = ["blobs: "]
    for blob in msg.blobs:
        lines += ["  - ", f'    name: "{blob.name}"', f"    data: {list(blob.data)}"]
    lines += [f"raw: {list(msg.raw)}", "inner: ", f'  name: "{msg.inner.name}"', f"  data: {list(msg.inner.data)}"]
    lines += [f"fixed: {list(msg.fixed)}"]
    return "\n".join(lines)


def test_big_uint8_arrays_inside_arrays_of_messages_and_nested_messages_render_exactly() -> None:
    msg = Frames(
        blobs=[Blob("a", os.urandom(5001)), Blob("b", b""), Blob("c", os.urandom(4097)), Blob("d", b"\x00\x0a")],
        raw=os.urandom(8193),
        inner=Blob("in", memoryview(os.urandom(6000))),  # type: ignore[arg-type]
        fixed=b"\x00\x63\x64\xff",
    )
    renderer = TextRenderer()
    text = expected_frames(msg)
    assert renderer.render(msg) == text
    chunks = renderer.render_chunks(msg)
    assert b"".join(chunks) == text.encode()
    assert len(chunks) == 1 + 2 * 4  # four big arrays (of one slice each), each spliced in as its own piece
    assert renderer.render_bytes(msg) == text.encode()


def test_a_megabyte_array_in_a_message_is_spliced_in_as_its_slices_never_joined() -> None:
    msg = Blob("img", os.urandom(1 << 20))
    chunks = TextRenderer().render_chunks(msg)
    assert b"".join(chunks) == f'name: "img"\ndata: {list(msg.data)}'.encode()
    assert chunks[0] == b'name: "img"\ndata: '
    assert len(chunks) == 1 + 1 + (1 << 20) // output._SLICE  # the text, "[", one piece per slice


def test_a_uint8_field_alone_renders_as_rostopic_echo_topic_field_does() -> None:
    data = os.urandom(9999)
    assert TextRenderer().render_chunks(memoryview(data), "uint8[]") == [reference(data)]
    assert TextRenderer(noarr=True).render(data, "uint8[]") == '"<array type: uint8, length: 9999>"'
