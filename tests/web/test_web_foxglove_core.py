"""The pure Foxglove protocol core and the byte-bounded queue: no sockets; hostile input by hypothesis."""

from __future__ import annotations

import json
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.web import foxglove as fg
from mrosd.web.access import AccessPolicy, is_loopback
from mrosd.web.queue import ByteQueue


def test_subprotocol_is_answered_as_offered() -> None:
    assert fg.choose_subprotocol(["foxglove.sdk.v1"]) == "foxglove.sdk.v1"
    assert fg.choose_subprotocol(["x", "foxglove.websocket.v1"]) == "foxglove.websocket.v1"
    assert fg.choose_subprotocol(["x"]) is None


def test_text_ops_decode_to_typed_structs() -> None:
    op = fg.decode_client_text('{"op":"subscribe","subscriptions":[{"id":1,"channelId":2}]}')
    assert op == fg.Subscribe([fg.Subscription(1, 2)])
    op = fg.decode_client_text(
        '{"op":"advertise","channels":[{"id":1,"topic":"/a","encoding":"ros1","schemaName":"std_msgs/String"}],"x":1}'
    )
    assert isinstance(op, fg.ClientAdvertise)
    assert op.channels[0].schema is None


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("[]", "not a JSON object"),
        ("nope", "not a JSON object"),
        ('{"op":"launchMissiles"}', "unknown op"),
        ('{"op":7}', "unknown op"),
        ('{"op":"subscribe","subscriptions":[{"id":-1,"channelId":2}]}', "malformed subscribe"),
        ('{"op":"subscribe","subscriptions":[{"id":4294967296,"channelId":2}]}', "malformed subscribe"),
        ('{"op":"unsubscribe"}', "malformed unsubscribe"),
    ],
)
def test_bad_text_ops_are_refused_with_a_reason(text: str, why: str) -> None:
    with pytest.raises(fg.ProtocolRefusal, match=why):
        fg.decode_client_text(text)


def test_too_long_lists_are_refused_whole() -> None:
    ids = list(range(fg.MAX_LIST + 1))
    with pytest.raises(fg.ProtocolRefusal):
        fg.decode_client_text(json.dumps({"op": "unsubscribe", "subscriptionIds": ids}))


@given(st.text(max_size=300))
def test_any_text_decodes_or_is_refused(text: str) -> None:
    try:
        fg.decode_client_text(text)
    except fg.ProtocolRefusal:
        pass


@given(st.binary(max_size=64))
def test_any_binary_decodes_or_is_refused(data: bytes) -> None:
    try:
        msg = fg.decode_client_binary(data)
    except fg.ProtocolRefusal:
        return
    assert len(msg.data) <= len(data)


@given(st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1), st.text(max_size=20), st.binary(max_size=40))
def test_service_call_request_round_trip(service: int, call: int, encoding: str, payload: bytes) -> None:
    enc = encoding.encode()
    frame = struct.pack("<BIII", 2, service, call, len(enc)) + enc + payload
    if len(enc) > fg.MAX_ENCODING:
        with pytest.raises(fg.ProtocolRefusal):
            fg.decode_client_binary(frame)
        return
    msg = fg.decode_client_binary(frame)
    assert isinstance(msg, fg.ServiceCallRequest)
    assert (msg.service_id, msg.call_id, msg.encoding, bytes(msg.data)) == (service, call, encoding, payload)


def test_an_encoding_length_beyond_the_frame_is_refused() -> None:
    with pytest.raises(fg.ProtocolRefusal, match="exceeds"):
        fg.decode_client_binary(struct.pack("<BIII", 2, 1, 1, 60) + b"ros1")


@given(st.integers(0, 2**32 - 1), st.integers(0, 2**64 - 1), st.binary(max_size=100))
def test_message_data_layout(sub_id: int, stamp: int, payload: bytes) -> None:
    frame = fg.message_data(sub_id, stamp, payload)
    assert frame[:13] == fg.message_data_prefix(sub_id, stamp)
    assert struct.unpack_from("<BIQ", frame) == (1, sub_id, stamp)
    assert frame[13:] == payload


def test_service_call_response_layout() -> None:
    frame = fg.service_call_response(3, 4, "ros1", b"\x01\x02")
    assert frame == struct.pack("<BIII", 3, 3, 4, 4) + b"ros1" + b"\x01\x02"


def test_connection_graph_update_is_a_diff() -> None:
    old: fg.SystemState = ({"/a": ["/n1"]}, {"/a": ["/n2"]}, {"/s": ["/n1"]})
    new: fg.SystemState = ({"/a": ["/n1", "/n3"]}, {}, {})
    update = json.loads(fg.connection_graph_update(old, new) or b"")
    assert update["publishedTopics"] == [{"name": "/a", "publisherIds": ["/n1", "/n3"]}]
    assert update["subscribedTopics"] == [{"name": "/a", "subscriberIds": []}]
    assert update["removedServices"] == ["/s"]
    assert update["removedTopics"] == []
    assert fg.connection_graph_update(new, new) is None
    assert json.loads(fg.connection_graph_update(new, fg.EMPTY_STATE) or b"")["removedTopics"] == ["/a"]


def test_queue_drops_oldest_by_bytes_and_counts() -> None:
    q: ByteQueue[str] = ByteQueue(10)
    assert q.put("a", 4) == 0
    assert q.put("b", 4) == 0
    assert q.put("c", 4) == 1  # "a" out
    assert (len(q), q.size, q.dropped, q.dropped_bytes) == (2, 8, 1, 4)
    assert q.get() == "b"
    assert q.take_unreported() == 1
    assert q.take_unreported() == 0


def test_queue_drop_oldest_counts_like_put() -> None:
    q: ByteQueue[str] = ByteQueue(10)
    q.put("a", 3)
    q.put("b", 4)
    assert q.drop_oldest() == 3
    assert (len(q), q.size, q.dropped, q.dropped_bytes, q.unreported) == (1, 4, 1, 3, 1)


def test_queue_passes_one_oversized_item_when_empty() -> None:
    q: ByteQueue[str] = ByteQueue(10)
    q.put("small", 3)
    q.put("huge", 100)
    assert (len(q), q.size, q.dropped) == (1, 100, 1)
    assert q.get() == "huge"


@given(st.integers(1, 1000), st.lists(st.integers(0, 300), max_size=50))
def test_queue_never_exceeds_its_bound_plus_one_item(bound: int, sizes: list[int]) -> None:
    q: ByteQueue[int] = ByteQueue(bound)
    for i, size in enumerate(sizes):
        q.put(i, size)
        assert q.size <= max(bound, size)
        assert q.dropped + len(q) == i + 1


def test_access_policy_globs_and_token() -> None:
    policy = AccessPolicy(topics=["/camera/*", "/tf"], services=[], token="s3cret")
    assert policy.allows_topic("/camera/image")
    assert policy.allows_topic("/tf")
    assert not policy.allows_topic("/tf_static")
    assert not policy.allows_service("/any")
    assert policy.allows_param("/any")
    assert policy.token_ok("s3cret")
    assert not policy.token_ok("nope")
    assert not policy.token_ok(None)
    assert AccessPolicy().token_ok(None)


def test_off_loopback_needs_a_token() -> None:
    from mrosd.errors import ConfigError

    assert is_loopback("127.0.0.1")
    assert is_loopback("::1")
    assert not is_loopback("0.0.0.0")
    AccessPolicy().check_bind("127.0.0.1")
    AccessPolicy(token="t").check_bind("0.0.0.0")
    with pytest.raises(ConfigError, match="token"):
        AccessPolicy().check_bind("0.0.0.0")


def test_trim_to_budget_drops_from_the_fullest_queue_and_keeps_the_newest() -> None:
    from mrosd.web.queue import trim_to_budget

    a: ByteQueue[str] = ByteQueue(100)
    b: ByteQueue[str] = ByteQueue(100)
    for i in range(5):
        a.put(f"a{i}", 10)
    b.put("b0", 30)
    trim_to_budget([a, b], 50, b)
    assert a.size + b.size <= 50
    assert b.get() == "b0"  # the newest stays
    huge: ByteQueue[str] = ByteQueue(10)
    huge.put("h", 500)
    trim_to_budget([a, huge], 50, huge)
    assert len(huge) == 1  # one message larger than the budget still flows
    assert len(a) == 0


@given(st.lists(st.tuples(st.sampled_from(["put", "get", "drop", "clear"]), st.integers(0, 1), st.integers(0, 50))))
def test_a_ledger_always_holds_the_sum_of_its_queues(ops: list[tuple[str, int, int]]) -> None:
    from mrosd.web.queue import Ledger

    ledger = Ledger()
    queues: list[ByteQueue[int]] = [ByteQueue(100, ledger), ByteQueue(60, ledger)]
    for op, which, size in ops:
        q = queues[which]
        if op == "put":
            q.put(size, size)
        elif op == "get" and len(q):
            q.get()
        elif op == "drop" and len(q):
            q.drop_oldest()
        elif op == "clear":
            q.clear()
        assert ledger.size == sum(x.size for x in queues)
