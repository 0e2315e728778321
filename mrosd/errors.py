"""Every exception mrosd raises, in one tree whose first level says who is at fault.

- ``LocalProtocolError``: our own caller misused the API (a bug in the calling code; fix the call).
- ``RemoteProtocolError``: another process sent bytes or a request we refuse; only that connection or call
  fails, never the daemon. ``RequestRefused`` (and its ``InvalidArgument``, ``HttpRefused``) is the
  well-formed request answered with a refusal code rather than a dropped connection.
- ``ConfigError``: the operator's configuration (file, environment, flags); the message names the key.
- ``Unavailable``: something needed is not there (a master that does not answer, a daemon that is down);
  nobody misbehaved, retrying later may work.
- The rest group errors by subject (``MsgError``, ``XmlRpcError``, ``MasterError``, ``IxmError``, ...);
  where the subject error also has a culprit it inherits both (``DeserializationError`` is a
  ``RemoteProtocolError``, ``MasterUnreachableError`` is ``Unavailable``).

Foreign exceptions are translated at the boundary with ``raise ... from exc``.
"""

from __future__ import annotations


class MrosError(Exception):
    """Root of every error mrosd raises on purpose; the message says what to fix."""


class LocalProtocolError(MrosError):
    """Our own caller asked for something the protocol does not allow."""


class RemoteProtocolError(MrosError):
    """A peer sent bytes that break the protocol; the connection to that peer is closed."""


class RequestRefused(RemoteProtocolError):
    """A peer's request is answered with a refusal (``code``: an XML-RPC status or an HTTP status)."""

    def __init__(self, message: str, code: int = -1) -> None:
        self.code = code
        super().__init__(message)


class InvalidArgument(RequestRefused):
    """An argument of a peer's call failed validation; the message goes back to the caller with code -1."""


class HttpRefused(RequestRefused):
    """An HTTP request refused with ``status`` and the short ``text`` body to send before closing."""

    def __init__(self, status: int, text: bytes) -> None:
        self.status = status
        self.text = text
        super().__init__(text.decode("utf-8", "replace").strip() or f"HTTP {status}", status)


class Unavailable(MrosError):
    """Something needed is not there or does not answer in time; nobody misbehaved, a retry may work."""


class HandshakeError(RemoteProtocolError):
    """A TCPROS connection header was refused (type or md5 mismatch, missing field)."""


class MsgError(MrosError):
    """Problems with message types: unknown types, bad definitions, bad values."""


class MsgParseError(MsgError):
    """A .msg/.srv definition is malformed; carries the file and 1-based line."""

    def __init__(self, message: str, file: str = "<string>", line: int = 0) -> None:
        self.file = file
        self.line = line
        self.reason = message
        where = f"{file}:{line}" if line else file
        super().__init__(f"{where}: {message}")


class MsgNotFoundError(MsgError):
    """No definition for a message or service type was found on the search path."""


class MsgTooComplexError(MsgError):
    """A definition would cost more to load than its use allows: nested too deep, too many fields once nested
    types are expanded, too long, or not compiled within the time budget; the message names the type."""


class SerializationError(MsgError):
    """A value cannot be serialized as its declared type (wrong type, out of range, wrong length)."""


class DeserializationError(MsgError, RemoteProtocolError):
    """Bytes do not decode as the expected type (truncated, oversized, trailing data)."""


class XmlRpcError(MrosError):
    """An XML-RPC call failed: transport error, timeout, fault, or malformed response."""


class XmlRpcFault(XmlRpcError):
    """An XML-RPC fault: raised by a handler to answer with it, or by a client when a server sent one."""

    def __init__(self, code: int, message: str) -> None:
        self.code = code
        self.message = message
        super().__init__(f"XML-RPC fault {code}: {message}")


class MasterError(MrosError):
    """The master answered a call with a failure or error code; carries code and status message."""

    def __init__(self, method: str, code: int, status: str) -> None:
        self.method = method
        self.code = code
        self.status = status
        super().__init__(f"master {method}: {status} (code {code})")


class MasterUnreachableError(MasterError, Unavailable):
    """The ROS master could not be reached at its URI."""

    def __init__(self, uri: str, reason: str) -> None:
        self.uri = uri
        super().__init__("connect", -1, f"cannot reach the ROS master at {uri}: {reason}")


class InvalidNameError(MrosError):
    """A ROS graph name is invalid."""


class ServiceError(MrosError):
    """A service call failed: the server returned an error string or the connection broke."""


class IxmError(MrosError):
    """IXM failures: unknown key, wrong type or size, daemon unreachable."""


class IxmPermissionError(IxmError):
    """The daemon's access rules do not grant this process the requested mode on a key."""


class ConfigError(MrosError):
    """The daemon's configuration file or environment is invalid."""
