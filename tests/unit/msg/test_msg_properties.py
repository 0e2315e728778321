"""Property tests: every value round-trips, and no input bytes or definition text crash the decoders.

Untrusted input must only ever raise the typed errors (DeserializationError, MsgParseError), never
hang, never allocate from a length that the buffer cannot back, never raise anything else.
"""

from __future__ import annotations

import struct
from array import array
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrosd.errors import DeserializationError, MsgError
from mrosd.msg import Duration, Time, get_message_class, load_type
from mrosd.msg.loader import view_decoder
from mrosd.msg.parser import parse_definition, parse_msg, parse_srv
from mrosd.msg.runtime import ZERO_COPY_MIN
from mrosd.msg.spec import PRIMITIVE_FORMATS, Field
from mrosd.msg.typestore import TypeStore

KITCHEN_SINK = """\
# every kind of field in one type
byte B=-3
string S=  a # not a comment
bool flag
int8 i8
uint8 u8
char c
byte by
int16 i16
uint16 u16
int32 i32
uint32 u32
int64 i64
uint64 u64
float32 f32
float64 f64
string s
time t
duration d
uint8[] blob
uint8[4] quad
char[] chars
bool[] flags
bool[2] pair
int16[] shorts
float64[3] vec
float32[] floats
uint64[] bigs
string[] names
string[2] two_names
time[] stamps
duration[2] spans
std_msgs/Header header
geometry_msgs/Point32[] points
geometry_msgs/Pose[2] poses
sensor_msgs/PointField[] fields
std_msgs/Empty[] empties
"""

TYPES = [
    "std_msgs/String",
    "std_msgs/Header",
    "std_msgs/Float64MultiArray",
    "sensor_msgs/CameraInfo",
    "sensor_msgs/PointCloud2",
    "sensor_msgs/JointState",
    "nav_msgs/OccupancyGrid",
    "visualization_msgs/MarkerArray",
    "diagnostic_msgs/DiagnosticArray",
    "trajectory_msgs/JointTrajectory",
    "rosgraph_msgs/Log",
]

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1),
    "byte": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "char": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}


def element(base: str, store: TypeStore) -> st.SearchStrategy[Any]:
    if base == "bool":
        return st.booleans()
    if base in _INT_RANGES:
        low, high = _INT_RANGES[base]
        return st.integers(low, high)
    if base == "float32":
        return st.floats(width=32, allow_nan=False)
    if base == "float64":
        return st.floats(allow_nan=False)
    if base == "string":
        return st.text(max_size=20)
    if base == "time":
        return st.builds(Time, st.integers(0, 2**32 - 1), st.integers(0, 999_999_999))
    if base == "duration":
        return st.builds(Duration, st.integers(-(2**31), 2**31 - 1), st.integers(0, 999_999_999))
    return message(get_message_class(base), store)


def field_strategy(f: Field, store: TypeStore) -> st.SearchStrategy[Any]:
    item = element(f.base, store)
    if not f.is_array:
        return item
    if f.base in ("uint8", "char"):
        return st.binary(min_size=f.length or 0, max_size=f.length if f.length is not None else 40)
    if f.length is not None:
        return st.lists(item, min_size=f.length, max_size=f.length)
    items = st.lists(item, max_size=4)
    if f.base in PRIMITIVE_FORMATS and f.base != "bool":
        code = PRIMITIVE_FORMATS[f.base][0]
        return items.map(lambda values: array(code, values))
    return items


def message(cls: Any, store: TypeStore) -> st.SearchStrategy[Any]:
    spec = store.msg_spec(cls._type) if "/" in cls._type else None
    fields = spec.fields if spec is not None else ()
    return st.builds(cls, **{f.name: field_strategy(f, store) for f in fields})


SINK = load_type("mros_test_msgs/KitchenSink", KITCHEN_SINK)


class _SinkStore(TypeStore):
    def msg_spec(self, name: str) -> Any:
        if name == "mros_test_msgs/KitchenSink":
            return parse_msg(KITCHEN_SINK, name)
        return super().msg_spec(name)


STORE = _SinkStore()
CLASSES = [SINK, *(get_message_class(name) for name in TYPES)]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_every_value_round_trips_through_its_bytes(cls: Any, data: st.DataObject) -> None:
    msg = data.draw(message(cls, STORE))
    body = msg.serialize()
    back = cls.deserialize(body)
    assert back == msg
    assert back.serialize() == body
    assert cls.deserialize(memoryview(body)) == msg
    assert cls.deserialize(bytearray(body)) == msg
    if cls._fixed_size is not None:
        assert len(body) == cls._fixed_size


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_every_truncation_and_extension_is_a_deserialization_error(cls: Any, data: st.DataObject) -> None:
    body = data.draw(message(cls, STORE)).serialize()
    cut = data.draw(st.integers(0, max(0, len(body) - 1)))
    if cut < len(body):
        with pytest.raises(DeserializationError):
            cls.deserialize(body[:cut])
    with pytest.raises(DeserializationError):
        cls.deserialize(body + data.draw(st.binary(min_size=1, max_size=8)))


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=150, deadline=None)
@given(junk=st.binary(max_size=300))
def test_random_bytes_decode_or_raise_deserialization_error(cls: Any, junk: bytes) -> None:
    try:
        msg = cls.deserialize(junk)
    except DeserializationError:
        return
    assert isinstance(msg, cls)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_a_corrupted_length_never_allocates_or_hangs(cls: Any, data: st.DataObject) -> None:
    body = bytearray(data.draw(message(cls, STORE)).serialize())
    if len(body) < 4:
        return
    at = data.draw(st.integers(0, len(body) - 4))
    body[at : at + 4] = struct.pack("<I", data.draw(st.sampled_from([2**32 - 1, 2**31, 10**9, len(body) + 1])))
    try:
        cls.deserialize(bytes(body))
    except DeserializationError:
        pass


def test_an_oversized_message_array_count_fails_before_looping() -> None:
    cls = get_message_class("visualization_msgs/MarkerArray")
    with pytest.raises(DeserializationError, match="markers"):
        cls.deserialize(struct.pack("<I", 2**32 - 1))


def test_empty_message_arrays_are_bounded() -> None:
    with pytest.raises(DeserializationError, match="empties"):
        SINK.deserialize(SINK().serialize()[:-4] + struct.pack("<I", 2**32 - 1))


def test_invalid_utf8_is_replaced_as_genpy_does() -> None:
    cls = get_message_class("std_msgs/String")
    assert cls.deserialize(b"\x02\x00\x00\x00\xff\xfe").data == "\ufffd\ufffd"


_LINE = st.one_of(
    st.text(max_size=40),
    st.sampled_from(["int32 x", "string s=", "Header h", "uint8[3 x", "a/b/c y", "float64[] v # c", "bool B=True"]),
)


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(_LINE, max_size=8))
def test_parsers_raise_only_msg_parse_errors(lines: list[str]) -> None:
    text = "\n".join(lines)
    parsers = [lambda: parse_msg(text, "p/T"), lambda: parse_srv(text, "p/S"), lambda: parse_definition("p/T", text)]
    for parse in parsers:
        try:
            parse()
        except MsgError:
            pass


@settings(max_examples=200, deadline=None)
@given(lines=st.lists(_LINE, max_size=6))
def test_load_type_raises_only_msg_errors(lines: list[str]) -> None:
    try:
        cls = load_type("fuzz_msgs/T", "\n".join(lines))
    except MsgError:
        return
    assert cls.deserialize(cls().serialize()) == cls()


# --- the view decoder (zero-copy subscribers read leased shared memory with it) ---------------------------


def _view_decode(cls: Any, body: bytes) -> tuple[Any, list[memoryview]]:
    views: list[memoryview] = []
    return view_decoder(cls)(memoryview(body).toreadonly(), cls, views), views


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_the_view_decoder_reads_what_deserialize_reads(cls: Any, data: st.DataObject) -> None:
    body = data.draw(message(cls, STORE)).serialize()
    msg, views = _view_decode(cls, body)
    assert msg == cls.deserialize(body)
    assert views == []  # nothing here reaches ZERO_COPY_MIN: copies, as deserialize makes
    cut = data.draw(st.integers(0, max(0, len(body) - 1)))
    if cut < len(body):
        with pytest.raises(DeserializationError):
            _view_decode(cls, body[:cut])
    with pytest.raises(DeserializationError):
        _view_decode(cls, body + data.draw(st.binary(min_size=1, max_size=8)))


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=100, deadline=None)
@given(junk=st.binary(max_size=300))
def test_the_view_decoder_on_random_bytes_decodes_as_deserialize_or_raises(cls: Any, junk: bytes) -> None:
    try:
        expected = cls.deserialize(junk)
    except DeserializationError:
        with pytest.raises(DeserializationError):
            _view_decode(cls, junk)
        return
    assert _view_decode(cls, junk)[0] == expected


def test_the_view_decoder_leaves_large_arrays_as_read_only_views_of_the_input() -> None:
    image = get_message_class("sensor_msgs/Image")
    payload = bytes(range(256)) * (ZERO_COPY_MIN // 256 + 1)
    body = image(height=1, width=len(payload), encoding="mono8", step=len(payload), data=payload).serialize()
    msg, views = _view_decode(image, body)
    assert views == [msg.data] and msg.data.readonly and bytes(msg.data) == payload and msg.encoding == "mono8"
    floats = get_message_class("std_msgs/Float32MultiArray")
    values = array("f", range(ZERO_COPY_MIN // 4))
    msg, views = _view_decode(floats, floats(data=values).serialize())
    assert len(views) == 1 and msg.data.format == "f" and list(msg.data) == list(values)
    small = floats(data=array("f", [1.5, 2.5]))
    msg, views = _view_decode(floats, small.serialize())
    assert views == [] and msg == small  # a small array is an array.array, as deserialize makes
