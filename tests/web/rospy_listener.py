"""A rospy node (Debian's, under /usr/bin/python3) for the rosbridge tests: one JSON line per event.

Usage: rospy_listener.py TOPIC [ACTION_NS]. Subscribes to TOPIC (geometry_msgs/Twist) and prints
``{"event": "message", "x": linear.x}`` for each message, after ``{"event": "ready"}``. With ACTION_NS it also
advertises the five actionlib topics under it (goal, cancel, status, feedback, result), which is how rosapi
finds an action server.
"""

import json
import sys

import rospy
from actionlib_msgs.msg import GoalID, GoalStatusArray
from geometry_msgs.msg import Twist


def out(**kw):
    print(json.dumps(kw), flush=True)


rospy.init_node("rospy_listener", disable_signals=True)
rospy.Subscriber(sys.argv[1], Twist, lambda m: out(event="message", x=m.linear.x), queue_size=100)
held = []
if len(sys.argv) > 2:
    ns = sys.argv[2]
    for leaf, cls in [("goal", GoalID), ("cancel", GoalID), ("status", GoalStatusArray)]:
        held.append(rospy.Publisher(f"{ns}/{leaf}", cls, queue_size=1))
    for leaf in ("feedback", "result"):
        held.append(rospy.Publisher(f"{ns}/{leaf}", GoalStatusArray, queue_size=1))
out(event="ready")
sys.stdin.read()  # until the test closes our stdin
