"""roslibjs's ``ActionClient`` (topics only: goal, cancel, status, feedback, result) through the daemon's rosbridge
port in headless Chromium, against examples/action_server.py (actionlib/TestAction at /test_action: one feedback
a step counting up, result 2 x goal)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rosenv import Processes
from tests.web.roslib_tf_browser import Browser, needs_chromium, page_server
from tests.web.webdaemon import WebDaemon

pytestmark = needs_chromium

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "action_server.py"
#: actionlib_msgs/GoalStatus
SUCCEEDED, PREEMPTED = 3, 2

ROBOT = Iterator[tuple[Browser, WebDaemon]]


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> ROBOT:
    tmp = tmp_path_factory.mktemp("roslibjs_action")
    procs = Processes(tmp)
    try:
        origin = page_server(procs)
        daemon = WebDaemon(procs, tmp, MROSD_WEB_ALLOWED_ORIGINS=origin)
        env = {"ROS_MASTER_URI": daemon.uri, "ROS_HOSTNAME": "127.0.0.1", "PATH": "/usr/bin:/bin"}
        server = procs.start([sys.executable, "-u", str(EXAMPLE)], env, stdout=subprocess.PIPE)
        wait_for_topic(daemon, "/test_action/status")
        assert server.poll() is None
        page = Browser(procs, origin, daemon.rosbridge_url)
        # roslibjs's ActionClient advertises the goal topic and subscribes to the others as it is made; a goal sent
        # at once can go before the bridge's links to the server exist (a goal of 1 s had its result lost): make
        # it first, and wait until the master lists the bridge's goal publisher and result subscriber
        page.send(cmd="action_client", server="/test_action", action="actionlib/TestAction")
        page.until("action_client")
        wait_for_bridge_ends(daemon)
        yield page, daemon
        page.close()
        daemon.close()
    finally:
        procs.close()


def wait_for_bridge_ends(daemon: WebDaemon, timeout: float = 20.0) -> None:
    """Until /test_action/goal has a publisher and /test_action/result, /test_action/feedback and
    /test_action/status a subscriber besides the server's own ends (the bridge's, registered)."""
    import time
    import xmlrpc.client

    deadline = time.monotonic() + timeout
    with xmlrpc.client.ServerProxy(daemon.uri) as master:
        while time.monotonic() < deadline:
            _, _, (pubs, subs, _) = master.getSystemState("/test")
            published = {name for name, nodes in pubs if nodes}
            subscribed = {name for name, nodes in subs if nodes}
            wanted = {f"/test_action/{t}" for t in ("result", "feedback", "status")}
            if "/test_action/goal" in published and wanted <= subscribed:
                return
            time.sleep(0.05)
    raise AssertionError(f"the bridge's action topics were not registered within {timeout} s")


def wait_for_topic(daemon: WebDaemon, topic: str, timeout: float = 20.0) -> None:
    import time
    import xmlrpc.client

    deadline = time.monotonic() + timeout
    with xmlrpc.client.ServerProxy(daemon.uri) as master:
        while time.monotonic() < deadline:
            _, _, topics = master.getPublishedTopics("/test", "")
            if any(name == topic for name, _ in topics):
                return
            time.sleep(0.05)
    raise AssertionError(f"{topic} not published within {timeout} s")


def test_roslibjs_goal_gets_every_feedback_and_the_result(browser: tuple[Browser, WebDaemon]) -> None:
    page, _ = browser
    page.send(cmd="action_goal", tag="five", server="/test_action", action="actionlib/TestAction", goal={"goal": 5})
    page.until("goal_sent", tag="five")
    result = page.until("result", tag="five", timeout=20)
    assert result["result"] == {"result": 10}
    assert result["status"]["status"] == SUCCEEDED
    feedback = [ev["feedback"]["feedback"] for ev in page.events if ev.get("event") == "feedback"]
    # every step's feedback, in order (the first may pass before the bridge's feedback subscription is linked)
    assert feedback[-1] == 5 and feedback == list(range(6 - len(feedback), 6)) and len(feedback) >= 4


def test_roslibjs_cancel_ends_the_goal_preempted(browser: tuple[Browser, WebDaemon]) -> None:
    page, _ = browser
    page.send(cmd="action_goal", tag="long", server="/test_action", action="actionlib/TestAction", goal={"goal": 50})
    page.until("feedback", tag="long", timeout=20)
    page.send(cmd="action_cancel", tag="long")
    result = page.until("result", tag="long", timeout=20)
    assert result["status"]["status"] == PREEMPTED
    assert result["result"] == {"result": 0}
