"""The TCPROS handshake rules: a peer's connection header against what we serve or expect.

Pure functions: given the peer's ``ConnectionHeader`` and our local topic or service, return the reply
header, or raise ``HandshakeError`` whose message is what the peer (or our user) needs to fix the problem.
md5 and type ``*`` are wildcards, as rospy/roscpp's AnyMsg and ``rostopic echo`` use them.
"""

from __future__ import annotations

from mrosd.errors import HandshakeError
from mrosd.wire.header import ConnectionHeader

WILDCARD = "*"


def _require(header: ConnectionHeader, *keys: str) -> None:
    missing = [k for k in keys if getattr(header, k) is None]
    if missing:
        raise HandshakeError(f"connection header is missing required field(s): {', '.join(missing)}")


def types_compatible(requested_type: str | None, requested_md5: str | None, msg_type: str, md5sum: str) -> str | None:
    """None when a requested (type, md5) matches ours, else the reason it does not."""
    if WILDCARD in (requested_md5, md5sum):
        if requested_type not in (None, WILDCARD, msg_type) and msg_type != WILDCARD:
            return f"topic types do not match: [{requested_type}] vs. [{msg_type}]"
        return None
    if requested_md5 != md5sum:
        return (
            f"md5sums do not match: [{requested_md5}] vs. [{md5sum}] "
            f"(requested type [{requested_type}], published type [{msg_type}])"
        )
    return None


def publisher_reply(
    request: ConnectionHeader,
    *,
    topic: str,
    msg_type: str,
    md5sum: str,
    message_definition: str,
    callerid: str,
    latching: bool,
) -> ConnectionHeader:
    """Check a subscriber's header against our published topic and build the publisher's reply.

    Raises:
        HandshakeError: a required field is missing, the topic differs, or type/md5 do not match.
    """
    _require(request, "topic", "md5sum", "callerid")
    if request.topic != topic:
        raise HandshakeError(f"topic [{request.topic}] is not published by [{callerid}] (it publishes [{topic}])")
    reason = types_compatible(request.type, request.md5sum, msg_type, md5sum)
    if reason is not None:
        raise HandshakeError(f"{reason} on topic [{topic}] from subscriber [{request.callerid}]")
    return ConnectionHeader(
        callerid=callerid,
        md5sum=md5sum,
        type=msg_type,
        message_definition=message_definition,
        latching="1" if latching else "0",
        topic=topic,
    )


def check_publisher_reply(
    reply: ConnectionHeader, *, topic: str, msg_type: str, md5sum: str, peer: str = "?"
) -> ConnectionHeader:
    """Check a publisher's answer to our subscription.

    Raises:
        HandshakeError: the publisher sent an error header, or its type/md5 do not match ours.
    """
    if reply.error is not None:
        raise HandshakeError(f"publisher [{reply.callerid or peer}] refused [{topic}]: {reply.error}")
    _require(reply, "md5sum")
    reason = types_compatible(reply.type, reply.md5sum, msg_type, md5sum)
    if reason is not None:
        raise HandshakeError(f"publisher [{reply.callerid or peer}] on [{topic}]: {reason}")
    return reply


def service_reply(
    request: ConnectionHeader,
    *,
    service: str,
    srv_type: str,
    md5sum: str,
    request_type: str,
    response_type: str,
    callerid: str,
) -> ConnectionHeader:
    """Check a service client's header against our service and build the server's reply.

    Raises:
        HandshakeError: a required field is missing, the service differs, or the md5 does not match.
    """
    _require(request, "service", "callerid")
    if not request.flag("probe"):
        _require(request, "md5sum")
    if request.service != service:
        raise HandshakeError(f"service [{request.service}] is not provided by [{callerid}] (it provides [{service}])")
    if request.md5sum not in (None, WILDCARD, md5sum):
        raise HandshakeError(
            f"request from [{request.callerid}]: md5sums do not match: [{request.md5sum}] vs. [{md5sum}] "
            f"for service [{service}] of type [{srv_type}]"
        )
    return ConnectionHeader(
        callerid=callerid,
        md5sum=md5sum,
        type=srv_type,
        request_type=request_type,
        response_type=response_type,
    )


def check_service_reply(reply: ConnectionHeader, *, service: str, md5sum: str) -> ConnectionHeader:
    """Check a service server's answer to our connection.

    Raises:
        HandshakeError: the server sent an error header or its md5 differs from ours.
    """
    if reply.error is not None:
        raise HandshakeError(f"service [{service}] refused the connection: {reply.error}")
    if reply.md5sum not in (None, WILDCARD, md5sum):
        raise HandshakeError(f"service [{service}]: md5sums do not match: [{md5sum}] (ours) vs. [{reply.md5sum}]")
    return reply


def error_header(message: str) -> ConnectionHeader:
    """The header that refuses a connection, as rospy and roscpp send it."""
    return ConnectionHeader(error=message)
