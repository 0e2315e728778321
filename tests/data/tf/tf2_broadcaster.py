"""tf2_ros broadcasters for the interop tests: world -> map static, map -> base moving at 20 Hz.

The moving frame's pose is a function of its stamp (``pose_at`` in the test module mirrors it); prints "up".
"""

import math

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def pose_at(t):
    yaw = 0.3 * t
    return [math.cos(t), math.sin(t), 0.5, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


def stamped(parent, child, stamp, pose):
    m = TransformStamped()
    m.header.frame_id, m.child_frame_id, m.header.stamp = parent, child, stamp
    t, r = m.transform.translation, m.transform.rotation
    t.x, t.y, t.z, r.x, r.y, r.z, r.w = pose
    return m


rospy.init_node("tf2_broadcaster")
static = tf2_ros.StaticTransformBroadcaster()
static.sendTransform(
    stamped("world", "map", rospy.Time.now(), [1.0, 2.0, 0.0, 0.0, 0.0, 0.38268343236508984, 0.9238795325112868])
)
moving = tf2_ros.TransformBroadcaster()
print("up", flush=True)
rate = rospy.Rate(20)
while not rospy.is_shutdown():
    now = rospy.Time.now()
    moving.sendTransform(stamped("map", "base", now, pose_at(now.secs % 1000 + now.nsecs * 1e-9)))
    rate.sleep()
