"""A small rospy node for mrosd's interop tests and benchmark; runs under Debian's /usr/bin/python3.

Modes (kind is string, image, cloud or coordinate; or mros for the mROS paper's section 5.4):
  echo KIND                  republish /ping on /pong (mros: answer the 1-byte String "c" with 2^(c-'A') bytes)
  ping KIND SIZES N          N round trips per size (comma-separated) on /ping -> /pong; "RTT SIZE ns ..."
  burst KIND SIZES N         N messages per size back to back; prints "BURST SIZE received seconds",
                             then the same again on the warm connection: "WARM SIZE received seconds"
  talk KIND TOPIC LATCH      publish a known message (once if LATCH=1, else at 20 Hz)
  listen KIND TOPIC COUNT    print COUNT received messages, one line each
  server SERVICE             std_srvs/SetBool server; data=False raises an error
  client SERVICE             call SERVICE with True then False; print the outcomes
"""

import os
import sys
import threading
import time

import rospy
from genpy.dynamic import generate_dynamic
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import String
from std_srvs.srv import SetBool, SetBoolResponse

HERE = os.path.dirname(os.path.abspath(__file__))
COORDINATE_TYPE = "mros_bench/Coordinate"
with open(os.path.join(HERE, "msg", "Coordinate.msg")) as f:
    Coordinate = generate_dynamic(COORDINATE_TYPE, f.read())[COORDINATE_TYPE]

CLASSES = {"string": String, "mros": String, "image": Image, "cloud": PointCloud2, "coordinate": Coordinate}


def make(kind, size=0):
    if kind == "mros":  # one byte naming the size of the reply: 'A' + log2(size)
        return String(data=chr(ord("A") + max(0, size - 1).bit_length()))
    if kind == "cloud":
        fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyzi")]
        width = size // 16
        return PointCloud2(
            height=1, width=width, fields=fields, point_step=16, row_step=16 * width, is_dense=True, data=bytes(size)
        )
    if kind == "string":
        return String(data="x" * size if size else "hello from rospy")
    if kind == "image":
        data = bytes([7]) * size if size else bytes(range(6))
        width = size or 3
        return Image(height=1 if size else 2, width=width, encoding="mono8", step=width, data=data)
    return Coordinate(x=1.5, y=2.5, z=-3.0, time=rospy.Time(7, 8))


def describe(kind, m):
    if kind == "string":
        return m.data
    if kind == "image":
        return f"{m.height} {m.width} {m.encoding} {bytes(m.data).hex()}"
    return f"{m.x:g} {m.y:g} {m.z:g} {m.time.secs} {m.time.nsecs}"


def main():
    mode, kind = sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "string"
    rospy.init_node("rospy_" + mode, anonymous=True, disable_signals=True)
    if mode == "echo":
        pub = rospy.Publisher("/pong", CLASSES[kind], queue_size=1000)
        callback = pub.publish
        if kind == "mros":
            replies = [String(data="x" * (1 << code)) for code in range(16)]

            def callback(m):
                pub.publish(replies[ord(m.data[0]) - ord("A")])

        rospy.Subscriber("/ping", CLASSES[kind], callback, queue_size=1000, tcp_nodelay=True)
        print("up", flush=True)
        rospy.spin()
    elif mode in ("ping", "burst"):
        sizes, n = [int(x) for x in sys.argv[3].split(",")], int(sys.argv[4])
        cond = threading.Condition()
        state = {"received": 0, "last": 0}

        def on_pong(_msg):
            with cond:
                state["received"] += 1
                state["last"] = time.perf_counter_ns()
                cond.notify()

        pub = rospy.Publisher("/ping", CLASSES[kind], queue_size=1000)
        sub = rospy.Subscriber("/pong", CLASSES[kind], on_pong, queue_size=1000, tcp_nodelay=True)
        while pub.get_num_connections() == 0 or sub.get_num_connections() == 0:
            time.sleep(0.01)

        def wait_for(count, timeout):
            with cond:
                return cond.wait_for(lambda: state["received"] >= count, timeout)

        for size in sizes:
            msg = make(kind, size)
            if mode == "ping":
                for _ in range(20):
                    want = state["received"] + 1
                    pub.publish(msg)
                    if not wait_for(want, 5.0):
                        sys.exit(3)
                rtts = []
                for _ in range(n):
                    want = state["received"] + 1
                    t0 = time.perf_counter_ns()
                    pub.publish(msg)
                    if not wait_for(want, 5.0):
                        sys.exit(3)
                    rtts.append(state["last"] - t0)
                print(f"RTT {size} " + " ".join(map(str, rtts)), flush=True)
            else:
                for label in ("BURST", "WARM"):  # on the new connection, then again on the warm one
                    start = state["received"]
                    t0 = time.perf_counter_ns()
                    for _ in range(n):
                        pub.publish(msg)
                    before = -1
                    while state["received"] != before and state["received"] - start < n:
                        before = state["received"]
                        wait_for(start + n, 1.0)
                    got = state["received"] - start
                    print(f"{label} {size} {got} {(state['last'] - t0) / 1e9:.6f}", flush=True)
    elif mode == "talk":
        topic, latch = sys.argv[3], sys.argv[4] == "1"
        pub = rospy.Publisher(topic, CLASSES[kind], queue_size=10, latch=latch)
        print("up", flush=True)
        if latch:
            pub.publish(make(kind))
            rospy.spin()
        while not rospy.is_shutdown():
            pub.publish(make(kind))
            time.sleep(0.05)
    elif mode == "listen":
        topic, count = sys.argv[3], int(sys.argv[4])
        done = threading.Event()
        seen = [0]

        def on_msg(m):
            if seen[0] < count:
                print(describe(kind, m), flush=True)
            seen[0] += 1
            if seen[0] >= count:
                done.set()

        rospy.Subscriber(topic, CLASSES[kind], on_msg)
        print("up", flush=True)
        done.wait(60)
    elif mode == "server":

        def handle(req):
            if not req.data:
                raise rospy.ServiceException("no from rospy")
            return SetBoolResponse(success=True, message="rospy got True")

        rospy.Service(sys.argv[2], SetBool, handle)
        print("up", flush=True)
        rospy.spin()
    elif mode == "client":
        rospy.wait_for_service(sys.argv[2], timeout=20)
        proxy = rospy.ServiceProxy(sys.argv[2], SetBool)
        resp = proxy(True)
        print(f"OK {resp.success} {resp.message}", flush=True)
        try:
            proxy(False)
            print("NO ERROR", flush=True)
        except rospy.ServiceException as exc:
            print(f"ERROR {exc}", flush=True)


if __name__ == "__main__":
    main()
