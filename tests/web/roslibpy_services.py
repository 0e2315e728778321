"""A roslibpy client (PyPI) driven by tests/web/test_web_rosbridge_types.py: one JSON line per result.

Usage: python roslibpy_services.py HOST PORT. On ``{"cmd": "advertise", "service", "type"}`` it provides the
service (AddTwoInts-shaped: ``sum = a + b``; its handler returns ``"result"``, True unless given: roslibpy's
own ROS 1 test returns False and expects the sum); on ``{"cmd": "call", "service", "args"}`` it calls one and prints
the response or the error roslibpy raises (with ``"retry": seconds``, calling again until it answers: a ROS
node's service is callable once the bridge has probed its type).
"""

import json
import sys
import time
from collections.abc import Callable

import roslibpy


def out(**kw: object) -> None:
    print(json.dumps(kw), flush=True)


def adder(result: bool) -> Callable[[dict, dict], bool]:
    def add(request: dict, response: dict) -> bool:
        response["sum"] = request["a"] + request["b"]
        return result

    return add


ros = roslibpy.Ros(host=sys.argv[1], port=int(sys.argv[2]))
ros.run(timeout=20)
out(event="connected")
provided = []
for line in sys.stdin:
    cmd = json.loads(line)
    service = roslibpy.Service(ros, cmd["service"], cmd.get("type", ""))
    if cmd["cmd"] == "advertise":
        service.advertise(adder(cmd.get("result", True)))
        provided.append(service)
        out(event="advertised", service=cmd["service"])
    elif cmd["cmd"] == "call":
        deadline = time.monotonic() + cmd.get("retry", 0)
        while True:
            try:
                response = service.call(roslibpy.ServiceRequest(cmd["args"]), timeout=10)
            except Exception as exc:  # roslibpy.core.ServiceException: the bridge's result false, its message
                if time.monotonic() < deadline:
                    time.sleep(0.1)
                    continue
                out(event="failed", service=cmd["service"], error=str(exc))
            else:
                out(event="response", service=cmd["service"], values=dict(response))
            break
