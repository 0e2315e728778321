"""Debian's actionlib (rospy) on /test_action for the interop tests; prints one line per event.

rospy_action.py server            SimpleActionServer: feedback 1..goal every STEP s, result 2 x goal
rospy_action.py client GOAL       SimpleActionClient: prints "feedback N", then "done STATE RESULT"
rospy_action.py cancel GOAL N     as client, but cancels the goal after N feedback messages
"""

import sys

import actionlib
import rospy
from actionlib.msg import TestAction, TestFeedback, TestGoal, TestResult
from actionlib_msgs.msg import GoalStatus

STEP = 0.2


def server():
    def execute(goal):
        for step in range(1, goal.goal + 1):
            if srv.is_preempt_requested():
                srv.set_preempted()
                return
            srv.publish_feedback(TestFeedback(feedback=step))
            rospy.sleep(STEP)
        srv.set_succeeded(TestResult(result=2 * goal.goal))

    srv = actionlib.SimpleActionServer("/test_action", TestAction, execute, auto_start=False)
    srv.start()
    print("up", flush=True)
    rospy.spin()


def client(goal, cancel_after):
    cli = actionlib.SimpleActionClient("/test_action", TestAction)
    if not cli.wait_for_server(rospy.Duration(20)):
        print("no server", flush=True)
        return
    # wait_for_server checks the server's subscriptions to goal and cancel, not ours to its feedback and result:
    # a goal sent before they connect loses its first feedback (actionlib's own race, with any server). rospy
    # counts a connection before it is made (get_num_connections), so wait for the publisher's reply header:
    # the publisher takes a subscriber when it answers its header.
    subs = (cli.action_client.feedback_sub, cli.action_client.result_sub)

    def connected(sub):
        conns = list(sub.impl.connections)
        return bool(conns) and all("md5sum" in (getattr(c, "header", None) or {}) for c in conns)

    deadline = rospy.Time.now() + rospy.Duration(20)
    while not all(connected(sub) for sub in subs) and rospy.Time.now() < deadline:
        rospy.sleep(0.01)
    print("up", flush=True)
    seen = []

    def feedback(fb):
        seen.append(fb.feedback)
        print(f"feedback {fb.feedback}", flush=True)
        if cancel_after and len(seen) == cancel_after:
            cli.cancel_goal()

    cli.send_goal(TestGoal(goal=goal), feedback_cb=feedback)
    cli.wait_for_result(rospy.Duration(30))
    state = GoalStatus.to_string(cli.get_state())
    result = cli.get_result()
    print(f"done {state} {None if result is None else result.result}", flush=True)


if __name__ == "__main__":
    rospy.init_node("rospy_action", anonymous=True)
    mode = sys.argv[1]
    if mode == "server":
        server()
    elif mode == "client":
        client(int(sys.argv[2]), 0)
    else:
        client(int(sys.argv[2]), int(sys.argv[3]))
