"""``XmlRpcClient``: every outgoing XML-RPC call of a process part, over one aiohttp session.

Owns the call's transport: the per-call timeout (connect included), big request bodies streamed, replies
read to their end but never past ``MAX_REPLY_SIZE``, and every transport failure as one ``XmlRpcError``
naming the method and the URI. Must not know what is called; the bytes are ``mrosd.xmlrpc.codec``'s.
"""

from __future__ import annotations

import io
from typing import Any

import aiohttp

from mrosd import backports
from mrosd.errors import RemoteProtocolError, XmlRpcError
from mrosd.xmlrpc.codec import MAX_REPLY_SIZE, decode_response, encode_call

#: Default timeout for one outgoing call, connect included.
DEFAULT_TIMEOUT = 10.0


#: Request bodies from this size on are handed to aiohttp as a stream (written in chunks).
_LARGE_REQUEST = 1024 * 1024


async def _read_body(content: aiohttp.StreamReader) -> bytes | None:
    """The whole response body (every read until EOF, not just the first chunk); None beyond MAX_REPLY_SIZE."""
    chunks: list[bytes] = []
    size = 0
    while True:
        chunk = await content.read(MAX_REPLY_SIZE + 1 - size)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
        size += len(chunk)
        if size > MAX_REPLY_SIZE:
            return None


class XmlRpcClient:
    """One aiohttp session for all outgoing XML-RPC calls of a process part.

    Create it inside a running event loop (or let the first call do so) and ``aclose()`` it.
    """

    def __init__(self, timeout: float = DEFAULT_TIMEOUT, limit: int = 256) -> None:
        self._timeout = timeout
        self._limit = limit
        self._session: aiohttp.ClientSession | None = None

    def _get_session(self) -> aiohttp.ClientSession:
        if self._session is None or self._session.closed:
            connector = aiohttp.TCPConnector(limit=self._limit, limit_per_host=0, force_close=False)
            self._session = aiohttp.ClientSession(
                connector=connector,
                headers={"Content-Type": "text/xml", "User-Agent": "mrosd"},
            )
        return self._session

    async def call(self, uri: str, method: str, *params: Any, timeout: float | None = None) -> Any:
        """Call ``method`` on the server at ``uri`` and return its single result value.

        Raises:
            Fault: the server answered with a fault.
            XmlRpcError: the server is unreachable, timed out, or answered with garbage.
        """
        body = encode_call(method, params)
        session = self._get_session()
        limit = self._timeout if timeout is None else timeout
        # aiohttp warns that big bytes bodies block the loop; a BytesIO is written in chunks instead.
        data_out: bytes | io.BytesIO = body if len(body) < _LARGE_REQUEST else io.BytesIO(body)
        try:
            async with backports.timeout(limit), session.post(uri, data=data_out) as resp:
                if resp.status != 200:
                    raise XmlRpcError(f"{method} at {uri}: HTTP status {resp.status}")
                if resp.content_length is not None and resp.content_length > MAX_REPLY_SIZE:
                    raise XmlRpcError(
                        f"{method} at {uri}: response of {resp.content_length} bytes exceeds the"
                        f" {MAX_REPLY_SIZE >> 20} MiB any mrosd master sends (MAX_REPLY_SIZE)"
                    )
                data = await _read_body(resp.content)
                if data is None:
                    raise XmlRpcError(
                        f"{method} at {uri}: response exceeds the {MAX_REPLY_SIZE >> 20} MiB any mrosd master"
                        " sends (MAX_REPLY_SIZE)"
                    )
        except TimeoutError as exc:
            raise XmlRpcError(f"{method} at {uri}: no answer within {limit:g} s") from exc
        except (aiohttp.ClientError, OSError, ValueError) as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc or type(exc).__name__}") from exc
        try:
            return decode_response(data)
        except RemoteProtocolError as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc}") from exc

    async def aclose(self) -> None:
        """Close the session and its pooled connections."""
        if self._session is not None:
            await self._session.close()
            self._session = None

    async def __aenter__(self) -> XmlRpcClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
