"""The Foxglove WebSocket protocol (``foxglove.websocket.v1``) as pure functions over text and bytes.

No sockets here (the aiohttp shell is ``mrosd.web.foxglove_server``): client text frames decode into
typed ops, client binary frames into ``ClientMessageData`` / ``ServiceCallRequest``, and every server
message has an encoder. Everything a client sends is untrusted: sizes are checked against the bytes that
actually arrived, ids are bounded to uint32, lists are bounded, and every refusal is a ``ProtocolRefusal``
whose text goes back to the client in a status message (the connection stays up).

Binary layouts (little-endian), as the protocol specification defines them:
  server: 1 messageData   op u8, subscriptionId u32, receiptTimestamp u64 (ns), payload
          2 time          op u8, timestamp u64 (ns)
          3 serviceCallResponse  op u8, serviceId u32, callId u32, encodingLength u32, encoding, payload
          4 fetchAssetResponse   op u8, requestId u32, status u8 (0 ok, 1 error), errorLength u32, error, data
  client: 1 messageData   op u8, channelId u32, payload
          2 serviceCallRequest   op u8, serviceId u32, callId u32, encodingLength u32, encoding, payload
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from typing import Annotated, Any, Final, Literal

import msgspec

from mrosd.errors import RemoteProtocolError
from mrosd.web.jsonvalue import TooDeep, check_depth, decode_bounded

__all__ = [
    "SUBPROTOCOLS",
    "Channel",
    "ClientAdvertise",
    "ClientChannel",
    "ClientMessageData",
    "ClientOp",
    "ClientUnadvertise",
    "FetchAsset",
    "GetParameters",
    "Parameter",
    "ProtocolRefusal",
    "ServiceCallRequest",
    "SetParameters",
    "Subscribe",
    "SubscribeConnectionGraph",
    "SubscribeParameterUpdates",
    "Unsubscribe",
    "UnsubscribeConnectionGraph",
    "UnsubscribeParameterUpdates",
    "binary_frame_head",
    "choose_subprotocol",
    "decode_client_binary",
    "decode_client_text",
    "encode_json",
    "fetch_asset_error",
    "fetch_asset_head",
    "message_data",
    "message_data_head",
    "message_data_prefix",
    "service_call_response",
    "time_message",
]

#: Subprotocols we speak; the reply names the one the client offered (Foxglove's SDK offers the second).
SUBPROTOCOLS: Final = ("foxglove.websocket.v1", "foxglove.sdk.v1")

STATUS_INFO: Final = 0
STATUS_WARNING: Final = 1
STATUS_ERROR: Final = 2

OP_MESSAGE_DATA: Final = 1
OP_TIME: Final = 2
OP_SERVICE_CALL_RESPONSE: Final = 3
OP_FETCH_ASSET_RESPONSE: Final = 4
FETCH_ASSET_OK: Final = 0
FETCH_ASSET_ERROR: Final = 1
CLIENT_OP_MESSAGE_DATA: Final = 1
CLIENT_OP_SERVICE_CALL_REQUEST: Final = 2

#: Most entries one client op may list (subscriptions, channels, parameter names): a request for more is
#: refused whole, so one frame cannot make the daemon allocate per-entry state without bound.
MAX_LIST: Final = 4096
#: Longest encoding name in a service call request (real ones are "ros1", "cdr", "json").
MAX_ENCODING: Final = 64

U32 = Annotated[int, msgspec.Meta(ge=0, le=0xFFFFFFFF)]
Name = Annotated[str, msgspec.Meta(max_length=4096)]

_MESSAGE_DATA = struct.Struct("<BIQ")
_TIME = struct.Struct("<BQ")
_CALL = struct.Struct("<BIII")
_CLIENT_DATA = struct.Struct("<BI")
_FETCH_ASSET = struct.Struct("<BIBI")


class ProtocolRefusal(RemoteProtocolError):
    """A client frame we refuse; the text goes back in a status message and the connection stays up."""


def choose_subprotocol(offered: Iterable[str]) -> str | None:
    """The first subprotocol the client offered that we speak (its spelling kept), or None."""
    for proto in offered:
        if proto.strip() in SUBPROTOCOLS:
            return proto.strip()
    return None


# --- client ops (JSON text frames) ------------------------------------------------------------------


class _Op(msgspec.Struct, tag_field="op", frozen=True):
    pass


class Subscription(msgspec.Struct, frozen=True):
    id: U32
    channelId: U32


class Subscribe(_Op, tag="subscribe", frozen=True):
    subscriptions: Annotated[list[Subscription], msgspec.Meta(max_length=MAX_LIST)]


class Unsubscribe(_Op, tag="unsubscribe", frozen=True):
    subscriptionIds: Annotated[list[U32], msgspec.Meta(max_length=MAX_LIST)]


class ClientChannel(msgspec.Struct, frozen=True):
    id: U32
    topic: Name
    encoding: Name
    schemaName: Name
    schema: str | None = None
    schemaEncoding: str | None = None


class ClientAdvertise(_Op, tag="advertise", frozen=True):
    channels: Annotated[list[ClientChannel], msgspec.Meta(max_length=MAX_LIST)]


class ClientUnadvertise(_Op, tag="unadvertise", frozen=True):
    channelIds: Annotated[list[U32], msgspec.Meta(max_length=MAX_LIST)]


class Parameter(msgspec.Struct, frozen=True, omit_defaults=True):
    name: Name
    value: Any = None
    type: Literal["byte_array", "float64", "float64_array"] | None = None


class GetParameters(_Op, tag="getParameters", frozen=True):
    parameterNames: Annotated[list[Name], msgspec.Meta(max_length=MAX_LIST)]
    id: str | None = None


class SetParameters(_Op, tag="setParameters", frozen=True):
    parameters: Annotated[list[Parameter], msgspec.Meta(max_length=MAX_LIST)]
    id: str | None = None


class SubscribeParameterUpdates(_Op, tag="subscribeParameterUpdates", frozen=True):
    parameterNames: Annotated[list[Name], msgspec.Meta(max_length=MAX_LIST)]


class UnsubscribeParameterUpdates(_Op, tag="unsubscribeParameterUpdates", frozen=True):
    parameterNames: Annotated[list[Name], msgspec.Meta(max_length=MAX_LIST)]


class SubscribeConnectionGraph(_Op, tag="subscribeConnectionGraph", frozen=True):
    pass


class UnsubscribeConnectionGraph(_Op, tag="unsubscribeConnectionGraph", frozen=True):
    pass


class FetchAsset(_Op, tag="fetchAsset", frozen=True):
    uri: Name
    requestId: U32


class Throttle(_Op, tag="x-mrosd.throttle", frozen=True):
    """mrosd's extension: send at most ``maxRate`` messages/s of a subscription, the latest only (0: all).

    The page's live views ask for it: a 1 kHz topic shown as a tree costs the browser 20 messages a second,
    and what a slow tab skips is replaced, never queued.
    """

    subscriptionId: U32
    maxRate: Annotated[float, msgspec.Meta(ge=0, le=1e6)]


class SubscribeStats(_Op, tag="x-mrosd.subscribeStats", frozen=True):
    """mrosd's extension: report every advertised topic's Hz and bytes/s once a second (``x-mrosd.topicStats``)."""


class UnsubscribeStats(_Op, tag="x-mrosd.unsubscribeStats", frozen=True):
    pass


class SubscribeDelivery(_Op, tag="x-mrosd.subscribeDelivery", frozen=True):
    """mrosd's extension: report this client's per-subscription sent/dropped/queued counts when they change
    (``x-mrosd.delivery``). Asked for, never sent unasked: Foxglove's own clients report an op they do not
    know as an error."""


class NodeDetails(_Op, tag="x-mrosd.nodeDetails", frozen=True):
    """mrosd's extension: a node's URI, host, pid and whether it answers (``x-mrosd.nodeDetails`` reply)."""

    node: Name
    id: str | None = None


class ImageSettings(_Op, tag="x-mrosd.imageSettings", frozen=True):
    """mrosd's extension: the encoder settings of a ``T/compressed`` topic mrosd makes (``mrosd.web.compressed``),
    one per topic, shared by every client, the last writer wins; the fields left out keep their value. The
    answer (also to an op with none of them) is ``x-mrosd.imageSettings`` with the topic's settings now."""

    topic: Name
    quality: Annotated[int, msgspec.Meta(ge=1, le=100)] | None = None
    maxWidth: Annotated[int, msgspec.Meta(ge=0, le=16384)] | None = None
    maxRate: Annotated[float, msgspec.Meta(ge=0, le=240)] | None = None


ClientOp = (
    Throttle
    | ImageSettings
    | SubscribeStats
    | UnsubscribeStats
    | SubscribeDelivery
    | NodeDetails
    | Subscribe
    | Unsubscribe
    | ClientAdvertise
    | ClientUnadvertise
    | GetParameters
    | SetParameters
    | SubscribeParameterUpdates
    | UnsubscribeParameterUpdates
    | SubscribeConnectionGraph
    | UnsubscribeConnectionGraph
    | FetchAsset
)

_OP_NAMES = frozenset(
    {
        "subscribe",
        "unsubscribe",
        "advertise",
        "unadvertise",
        "getParameters",
        "setParameters",
        "subscribeParameterUpdates",
        "unsubscribeParameterUpdates",
        "subscribeConnectionGraph",
        "unsubscribeConnectionGraph",
        "fetchAsset",
        "x-mrosd.throttle",
        "x-mrosd.subscribeStats",
        "x-mrosd.unsubscribeStats",
        "x-mrosd.subscribeDelivery",
        "x-mrosd.nodeDetails",
        "x-mrosd.imageSettings",
    }
)
_op_decoder: msgspec.json.Decoder[ClientOp] = msgspec.json.Decoder(ClientOp)  # type: ignore[arg-type]


class _OpOnly(msgspec.Struct):
    op: Any = None


_op_peek = msgspec.json.Decoder(_OpOnly)


def decode_client_text(data: str | bytes) -> ClientOp:
    """One client JSON op; a parameter value may nest at most ``jsonvalue.MAX_DEPTH`` levels.

    Raises:
        ProtocolRefusal: not JSON, an unknown op, fields of the wrong shape (the message says which), or
            nested too deep (whatever the decoder would otherwise raise: never RecursionError).
    """
    try:
        op = decode_bounded(_op_decoder.decode, data)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        try:
            name = decode_bounded(_op_peek.decode, data).op
        except (msgspec.DecodeError, msgspec.ValidationError, ValueError):
            raise ProtocolRefusal(f"not a JSON object: {exc}") from None
        if not isinstance(name, str) or name not in _OP_NAMES:
            raise ProtocolRefusal(f"unknown op {_shown(name)}") from None
        raise ProtocolRefusal(f"malformed {name}: {exc}") from None
    except ValueError as exc:  # TooDeep, or more than memory holds
        raise ProtocolRefusal(f"not accepted: {exc}") from None
    if isinstance(op, SetParameters):
        for param in op.parameters:
            try:
                check_depth(param.value)
            except TooDeep as exc:
                raise ProtocolRefusal(f"setParameters {param.name}: the value is {exc}") from None
    return op


def _shown(op: object) -> str:
    """An op name for a refusal: a string (cut short), else only its JSON type (a nested value's repr recurses)."""
    return repr(op[:80]) if isinstance(op, str) else f"of type {type(op).__name__}"


# --- client binary frames ---------------------------------------------------------------------------


class ClientMessageData(msgspec.Struct, frozen=True):
    """A message a client publishes on one of the channels it advertised; ``data`` is a view of the frame."""

    channel_id: int
    data: memoryview


class ServiceCallRequest(msgspec.Struct, frozen=True):
    service_id: int
    call_id: int
    encoding: str
    data: memoryview


def decode_client_binary(frame: bytes | bytearray | memoryview) -> ClientMessageData | ServiceCallRequest:
    """One client binary frame (views into ``frame``, no copy of the payload).

    Raises:
        ProtocolRefusal: empty, unknown opcode, truncated, or an encoding length beyond the frame.
    """
    view = memoryview(frame).cast("B") if not isinstance(frame, memoryview) else frame.cast("B")
    if not view:
        raise ProtocolRefusal("empty binary message")
    op = view[0]
    if op == CLIENT_OP_MESSAGE_DATA:
        if len(view) < _CLIENT_DATA.size:
            raise ProtocolRefusal(f"truncated messageData ({len(view)} bytes)")
        _, channel = _CLIENT_DATA.unpack_from(view)
        return ClientMessageData(channel, view[_CLIENT_DATA.size :])
    if op == CLIENT_OP_SERVICE_CALL_REQUEST:
        if len(view) < _CALL.size:
            raise ProtocolRefusal(f"truncated serviceCallRequest ({len(view)} bytes)")
        _, service, call, enc_len = _CALL.unpack_from(view)
        start = _CALL.size
        if enc_len > MAX_ENCODING or start + enc_len > len(view):
            raise ProtocolRefusal(f"serviceCallRequest encoding length {enc_len} exceeds the frame or limit")
        try:
            encoding = bytes(view[start : start + enc_len]).decode("utf-8")
        except UnicodeDecodeError:
            raise ProtocolRefusal("serviceCallRequest encoding is not UTF-8") from None
        return ServiceCallRequest(service, call, encoding, view[start + enc_len :])
    raise ProtocolRefusal(f"unknown binary opcode {op}")


# --- server messages --------------------------------------------------------------------------------


class Channel(msgspec.Struct, frozen=True):
    """One advertised topic: ``schema`` is the full TCPROS message_definition, encoding ``ros1``."""

    id: int
    topic: str
    encoding: str
    schemaName: str
    schema: str
    schemaEncoding: str = "ros1msg"


_json = msgspec.json.Encoder()


def encode_json(op: str, **fields: Any) -> bytes:
    """A server JSON message ``{"op": op, **fields}`` (None fields are left out)."""
    return _json.encode({"op": op, **{k: v for k, v in fields.items() if v is not None}})


def server_info(
    name: str, capabilities: Sequence[str], *, session_id: str, metadata: dict[str, str] | None = None
) -> bytes:
    return encode_json(
        "serverInfo",
        name=name,
        capabilities=list(capabilities),
        supportedEncodings=["ros1"],
        metadata=metadata or {},
        sessionId=session_id,
    )


def status(level: int, message: str, status_id: str | None = None) -> bytes:
    return encode_json("status", level=level, message=message, id=status_id)


def message_data_prefix(subscription_id: int, timestamp_ns: int) -> bytes:
    """The 13 bytes before a messageData payload."""
    return _MESSAGE_DATA.pack(OP_MESSAGE_DATA, subscription_id, timestamp_ns)


def message_data(subscription_id: int, timestamp_ns: int, payload: bytes | bytearray | memoryview) -> bytes:
    """A whole messageData frame: the prefix and the payload exactly as received from TCPROS."""
    return _MESSAGE_DATA.pack(OP_MESSAGE_DATA, subscription_id, timestamp_ns) + payload


_WS_LEN7 = struct.Struct("!BB")
_WS_LEN16 = struct.Struct("!BBH")
_WS_LEN64 = struct.Struct("!BBQ")
#: FIN and the binary opcode: a whole binary message in one frame (RFC 6455 section 5.2)
_WS_FIN_BINARY = 0x82


def binary_frame_head(length: int) -> bytes:
    """The head of an unmasked (server-to-client) WebSocket frame carrying ``length`` bytes of one binary
    message: what precedes them on the wire."""
    if length < 126:
        return _WS_LEN7.pack(_WS_FIN_BINARY, length)
    if length < 65536:
        return _WS_LEN16.pack(_WS_FIN_BINARY, 126, length)
    return _WS_LEN64.pack(_WS_FIN_BINARY, 127, length)


def message_data_head(subscription_id: int, timestamp_ns: int, payload_length: int) -> bytes:
    """The WebSocket frame head and messageData prefix for a payload of ``payload_length`` bytes.

    Written to the socket before the payload itself, which is then sent from the buffer it was received in:
    one frame per message costs no copy of the payload, whatever the number of clients."""
    return binary_frame_head(_MESSAGE_DATA.size + payload_length) + _MESSAGE_DATA.pack(
        OP_MESSAGE_DATA, subscription_id, timestamp_ns
    )


def time_message(timestamp_ns: int) -> bytes:
    return _TIME.pack(OP_TIME, timestamp_ns)


def service_call_response(
    service_id: int, call_id: int, encoding: str, payload: bytes | bytearray | memoryview
) -> bytes:
    enc = encoding.encode()
    return _CALL.pack(OP_SERVICE_CALL_RESPONSE, service_id, call_id, len(enc)) + enc + payload


def fetch_asset_head(request_id: int) -> bytes:
    """What precedes an asset's bytes in a successful fetchAssetResponse (the reader puts the file behind it)."""
    return _FETCH_ASSET.pack(OP_FETCH_ASSET_RESPONSE, request_id, FETCH_ASSET_OK, 0)


def fetch_asset_error(request_id: int, message: str) -> bytes:
    """A fetchAssetResponse saying why the asset is not sent (no data)."""
    text = message.encode("utf-8", "replace")
    return _FETCH_ASSET.pack(OP_FETCH_ASSET_RESPONSE, request_id, FETCH_ASSET_ERROR, len(text)) + text


#: ``(publishers, subscribers, services)`` as getSystemState gives them: ``{name: [node, ...]}`` each.
SystemState = tuple[dict[str, list[str]], dict[str, list[str]], dict[str, list[str]]]
EMPTY_STATE: SystemState = ({}, {}, {})


def connection_graph_update(old: SystemState, new: SystemState) -> bytes | None:
    """The ``connectionGraphUpdate`` that turns ``old`` into ``new`` (None when nothing changed).

    Entries are sent whole for every topic or service whose node list changed; topics that lost their last
    publisher and subscriber, and services that vanished, are listed as removed.
    """
    (old_pubs, old_subs, old_srvs), (pubs, subs, srvs) = old, new
    gone_topics = sorted((set(old_pubs) | set(old_subs)) - (set(pubs) | set(subs)))
    gone_services = sorted(set(old_srvs) - set(srvs))
    kept = (set(old_pubs) | set(old_subs) | set(pubs) | set(subs)) - set(gone_topics)
    published = [
        {"name": n, "publisherIds": sorted(pubs.get(n, []))}
        for n in sorted(kept)
        if sorted(old_pubs.get(n, [])) != sorted(pubs.get(n, []))
    ]
    subscribed = [
        {"name": n, "subscriberIds": sorted(subs.get(n, []))}
        for n in sorted(kept)
        if sorted(old_subs.get(n, [])) != sorted(subs.get(n, []))
    ]
    services = [{"name": n, "providerIds": sorted(ids)} for n, ids in sorted(srvs.items()) if old_srvs.get(n) != ids]
    if not (published or subscribed or services or gone_topics or gone_services):
        return None
    return encode_json(
        "connectionGraphUpdate",
        publishedTopics=published,
        subscribedTopics=subscribed,
        advertisedServices=services,
        removedTopics=gone_topics,
        removedServices=gone_services,
    )
