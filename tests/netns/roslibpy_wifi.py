"""roslibpy (PyPI, its asyncio transport, which offers permessage-deflate) subscribed with ``compression: cbor``
for the Wi-Fi lab: one JSON line per message received (topic, stamp, arrival time), after one line naming the
negotiated extensions.

Usage: python roslibpy_wifi.py HOST PORT TOKEN TOPIC:TYPE ... . roslibpy has no CBOR decoder of its own (its
asyncio protocol refuses binary frames), so this script decodes them with cbor2 and hands them to the same
handlers; its ``Topic`` only lists png and none, so ``compression`` is set after construction.
"""

import json
import sys
import threading
import time

import cbor2
import roslibpy
from roslibpy.comm import comm_asyncio


def out(**kw: object) -> None:
    print(json.dumps(kw), flush=True)


_on_message = comm_asyncio.AsyncioRosBridgeProtocol.onMessage


def _on_binary(self, payload, isBinary):
    if not isBinary:
        return _on_message(self, payload, isBinary)
    msg = cbor2.loads(payload)
    handler = self._message_handlers.get(msg.get("op"))
    if handler is not None:
        handler(roslibpy.Message(msg))
    return None


comm_asyncio.AsyncioRosBridgeProtocol.onMessage = _on_binary


def stamp_of(topic: str, msg: dict) -> float:
    if "header" in msg:
        s = msg["header"]["stamp"]
        return s["secs"] + s["nsecs"] * 1e-9
    return float(msg["data"])


host, port, token = sys.argv[1], int(sys.argv[2]), sys.argv[3]
ros = roslibpy.Ros(host=host, port=port, headers={"Authorization": f"Bearer {token}"}, transport="asyncio")
ros.run(timeout=20)
proto = ros.factory._proto
extensions = [str(e.EXTENSION_NAME) for e in getattr(proto, "websocket_extensions_in_use", [])]
out(event="open", extensions=",".join(extensions))
topics = []
for arg in sys.argv[4:]:
    name, msg_type = arg.split(":")
    topic = roslibpy.Topic(ros, name, msg_type)
    topic.compression = "cbor"

    def on(msg: dict, name: str = name) -> None:
        out(event="message", topic=name, stamp=stamp_of(name, msg), at=time.time())

    topic.subscribe(on)
    topics.append(topic)
out(event="subscribed")
threading.Event().wait()
