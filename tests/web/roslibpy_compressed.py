"""A roslibpy client (PyPI) for tests/web/test_web_compressed.py, one JSON line per result.

Usage: python roslibpy_compressed.py HOST PORT TOPIC COMPRESSION. Lists the topic through rosapi (its type
and ``topics_for_type``), then subscribes to it as sensor_msgs/CompressedImage with ``compression`` (``cbor``
or ``none``) and prints the first image's ``format`` and ``data`` (base64), then waits to be killed.
"""

import base64
import json
import sys
import threading

import roslibpy


def out(**kw: object) -> None:
    print(json.dumps(kw), flush=True)


host, port, topic, compression = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
ros = roslibpy.Ros(host=host, port=port)
ros.run(timeout=20)
kind = roslibpy.Service(ros, "/rosapi/topic_type", "rosapi/TopicType").call(
    roslibpy.ServiceRequest({"topic": topic}), timeout=10
)
same = roslibpy.Service(ros, "/rosapi/topics_for_type", "rosapi/TopicsForType").call(
    roslibpy.ServiceRequest({"type": "sensor_msgs/CompressedImage"}), timeout=10
)
out(event="topics", type=kind["type"], for_type=same["topics"])
done = threading.Event()


def on_image(msg: dict) -> None:
    if done.is_set():
        return
    data = msg["data"]
    if isinstance(data, (bytes, bytearray)):  # cbor: a byte string
        data = base64.b64encode(data).decode()
    out(event="image", format=msg["format"], data=data)
    done.set()


sub = roslibpy.Topic(ros, topic, "sensor_msgs/CompressedImage", compression=compression)
sub.subscribe(on_image)
done.wait(30)
threading.Event().wait(60)
