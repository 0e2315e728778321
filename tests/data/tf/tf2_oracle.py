"""Feed Debian's tf2_ros.Buffer (C++ tf2 underneath) transforms and answer lookups, as JSON on stdin/stdout.

stdin: {"transforms": [[parent, child, stamp_ns, [x, y, z, qx, qy, qz, qw], static, authority]],
        "queries": [[target, source, time_ns]]}
stdout: one JSON list, per query {"pose": [...], "stamp": ns} or {"error": name, "text": message}; then the
buffer's allFramesAsYAML text as {"yaml": ...}.
"""

import json
import sys

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped

spec = json.load(sys.stdin)
buf = tf2_ros.Buffer(cache_time=rospy.Duration(10), debug=False)
for parent, child, stamp, pose, static, authority in spec["transforms"]:
    m = TransformStamped()
    m.header.frame_id, m.child_frame_id = parent, child
    m.header.stamp = rospy.Time(0, stamp)
    t, r = m.transform.translation, m.transform.rotation
    t.x, t.y, t.z, r.x, r.y, r.z, r.w = pose
    if static:
        buf.set_transform_static(m, authority)
    else:
        buf.set_transform(m, authority)
out = []
for target, source, time in spec["queries"]:
    try:
        res = buf.lookup_transform(target, source, rospy.Time(0, time))
    except Exception as exc:
        out.append({"error": type(exc).__name__, "text": str(exc)})
        continue
    t, r = res.transform.translation, res.transform.rotation
    out.append({"pose": [t.x, t.y, t.z, r.x, r.y, r.z, r.w], "stamp": res.header.stamp.to_nsec()})
out.append({"yaml": buf.all_frames_as_yaml()})
json.dump(out, sys.stdout)
