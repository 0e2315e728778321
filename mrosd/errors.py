"""Every exception mrosd raises, in one flat hierarchy.

The split says who is at fault: ``LocalProtocolError`` means our caller misused the API,
``RemoteProtocolError`` means a peer sent bad bytes (only that connection is closed).
Foreign exceptions are translated at the boundary with ``raise ... from exc``.
"""

from __future__ import annotations


class MrosError(Exception):
    """Root of every error mrosd raises on purpose; the message says what to fix."""


class LocalProtocolError(MrosError):
    """Our own caller asked for something the protocol does not allow."""


class RemoteProtocolError(MrosError):
    """A peer sent bytes that break the protocol; the connection to that peer is closed."""


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


class SerializationError(MsgError):
    """A value cannot be serialized as its declared type (wrong type, out of range, wrong length)."""


class DeserializationError(MsgError, RemoteProtocolError):
    """Bytes do not decode as the expected type (truncated, oversized, trailing data)."""


class XmlRpcError(MrosError):
    """An XML-RPC call failed: transport error, timeout, fault, or malformed response."""


class MasterError(MrosError):
    """The master answered a call with a failure or error code; carries code and status message."""

    def __init__(self, method: str, code: int, status: str) -> None:
        self.method = method
        self.code = code
        self.status = status
        super().__init__(f"master {method}: {status} (code {code})")


class MasterUnreachableError(MasterError):
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
