"""A roslibpy client (PyPI) driven by tests/web/test_web_real_clients.py: it prints one JSON line per result.

Usage: python roslibpy_client.py HOST PORT. Subscribes /image (sha256 of the pixels), publishes /from_roslibpy,
calls /enable, reads /robot/name, then waits for the test to kill it.
"""

import base64
import hashlib
import json
import sys
import threading

import roslibpy


def out(**kw: object) -> None:
    print(json.dumps(kw), flush=True)


ros = roslibpy.Ros(host=sys.argv[1], port=int(sys.argv[2]))
ros.run(timeout=20)
out(event="connected")
got_image = threading.Event()


def on_image(msg: dict) -> None:
    data = base64.b64decode(msg["data"])
    out(event="image", len=len(data), sha256=hashlib.sha256(data).hexdigest(), width=msg["width"])
    got_image.set()


image = roslibpy.Topic(ros, "/image", "sensor_msgs/Image")
image.subscribe(on_image)
out(event="subscribed")
pub = roslibpy.Topic(ros, "/from_roslibpy", "std_msgs/String")
pub.advertise()
for line in sys.stdin:
    cmd = json.loads(line)
    if cmd["cmd"] == "publish":
        pub.publish(roslibpy.Message({"data": cmd["data"]}))
        out(event="published")
    elif cmd["cmd"] == "call":
        service = roslibpy.Service(ros, "/enable", "std_srvs/SetBool")
        response = service.call(roslibpy.ServiceRequest({"data": True}), timeout=10)
        out(event="response", values=dict(response))
    elif cmd["cmd"] == "param":
        out(event="param", value=roslibpy.Param(ros, "/robot/name").get(timeout=10))
