"""The control messages of a shared-memory topic connection (Unix stream socket), sans I/O.

Frames are length-prefixed msgpack, read by ``mrosd.ixm.channel.FdReader`` as IXM's control frames are;
descriptors travel beside them with SCM_RIGHTS (``FDS`` says how many each kind carries). Data never
goes through this socket:

- ``Attach`` (subscriber -> publisher, no descriptor): the token from requestTopic and the TCPROS
  connection header the subscriber would have sent over TCP.
- ``Attached`` (publisher -> subscriber, + three descriptors: the ring, read-only; the subscriber's own
  acknowledgement page, writable; its end of a Unix socket pair the publisher made, for wake-ups both
  ways): the publisher's connection header and the number of the first message to read (the latched one
  when there is one). Version 2 sent eventfds both ways instead, which the other side could make blocking.
- ``Refused``: why the publisher will not serve this subscriber (md5 mismatch, bad token); then it closes.
- ``Ring`` (publisher -> subscriber, + the new ring): a message did not fit, the old ring is retired.
- ``Progress`` (subscriber -> publisher): the subscriber's drop count, for the publisher's getBusStats.

The socket closing is the end of the connection, for either side: after a crash the kernel closes it.
"""

from __future__ import annotations

import msgspec

from mrosd.errors import RemoteProtocolError
from mrosd.wire.framing import encode_frame

__all__ = ["MAX_CONTROL_FRAME", "Attach", "Attached", "Message", "Progress", "Refused", "Ring", "decode", "encode"]

#: A connection header with a long message_definition fits easily; anything bigger is refused.
MAX_CONTROL_FRAME = 1 << 20


class Attach(msgspec.Struct, tag="attach", gc=False):
    token: str
    header: bytes
    #: leases the subscriber would like to hold at once (zero-copy views; 0: it copies every message out)
    leases: int = 0


class Attached(msgspec.Struct, tag="attached", gc=False):
    header: bytes
    first: int
    #: leases the publisher honours for this subscriber (its share of the pool; may be fewer than asked)
    leases: int = 0


class Refused(msgspec.Struct, tag="refused", gc=False):
    reason: str


class Ring(msgspec.Struct, tag="ring", gc=False):
    slots: int


class Progress(msgspec.Struct, tag="progress", gc=False):
    dropped: int
    received: int


Message = Attach | Attached | Refused | Ring | Progress
#: descriptors that come with each kind of message
FDS: dict[type, int] = {Attached: 3, Ring: 1}
_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(Message)


def encode(msg: Message) -> bytes:
    return encode_frame(_encoder.encode(msg))


def decode(body: bytes | bytearray) -> Message:
    """One frame body.

    Raises:
        RemoteProtocolError: it is not a control message.
    """
    try:
        msg: Message = _decoder.decode(body)
    except msgspec.DecodeError as exc:
        raise RemoteProtocolError(f"bad shared-memory control message: {exc}") from None
    return msg
