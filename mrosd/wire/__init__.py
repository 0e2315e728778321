"""The TCPROS wire format as pure functions and state machines (no sockets, no asyncio).

``header`` (connection headers), ``framing`` (length-prefixed frames: topics, service answers with their ok
byte, the IXM and shared-memory control sockets) and ``handshake`` (a peer's header against the local
topic or service). ``mrosd.tcpros`` (the asyncio nodes), ``mrosd.ixm`` and ``mrosd.shm`` build on them;
importing them loads nothing of the node stack.
"""
