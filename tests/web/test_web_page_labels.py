"""The page's first-contact details (issue 33, item 7), in headless Chromium against a running daemon: log times
are readable, a long node name is cut to fit its ellipse with the full name as its title, and the Topics table
does not count the page's own measuring subscriber (the daemon's web node) as a user's.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import ROS_PYTHON, Processes, ros_available, ros_env
from tests.web.test_web_page import Browser, page_url

pytestmark = [
    pytest.mark.interop,
    pytest.mark.skipif(not ros_available(), reason="real ROS 1 (Debian ros_comm) is not installed"),
    pytest.mark.skipif(
        shutil.which("node") is None or not (Path(__file__).parent / "node_modules" / "playwright-core").is_dir(),
        reason="node or playwright-core missing",
    ),
]

LONG = "/a_rather_long_robot_namespace/and_an_even_longer_node_name_for_the_graph"
ROSPY_TALKER = f"""
import rospy
from std_msgs.msg import String
rospy.init_node("{LONG.rsplit("/", 1)[1]}")
pub = rospy.Publisher("/chatter", String, queue_size=10)
rospy.Subscriber("/chatter", String, lambda m: None)
rate = rospy.Rate(10)
n = 0
while not rospy.is_shutdown():
    pub.publish(String("hello %d" % n))
    if n % 5 == 0:
        rospy.loginfo("talking %d", n)
    n += 1
    rate.sleep()
"""


@pytest.fixture
def running(procs: Processes, tmp_path: Path) -> Iterator[tuple[DaemonRun, str]]:
    run = DaemonRun(procs, tmp_path)
    try:
        status = run.ready()
        assert status.startswith("running:"), status
        yield run, page_url(status)
    finally:
        run.close()


def test_log_times_long_names_and_the_pages_own_subscriber(
    procs: Processes, tmp_path: Path, running: tuple[DaemonRun, str]
) -> None:
    run, url = running
    env = ros_env(run.uri, tmp_path, ROS_NAMESPACE=LONG.rsplit("/", 1)[0])
    procs.start([ROS_PYTHON, "-c", ROSPY_TALKER], env, stdout=None, stderr=None)
    browser = Browser(procs)

    browser.do("goto", url=url + "#graph")
    node = f"#graph g.node[data-name='{LONG}']"
    browser.until(f'document.querySelector("{node}")')
    shown = browser.eval(
        f"(() => {{ const g = document.querySelector(\"{node}\"); const t = g.querySelector('text');"
        " return { text: t.textContent, title: g.querySelector('title').textContent,"
        " width: t.getComputedTextLength(), rx: Number(g.querySelector('ellipse').getAttribute('rx')) }; })()"
    )
    assert shown["title"] == LONG
    assert shown["text"].startswith("…") and LONG.endswith(shown["text"][1:]), shown
    assert 0 < shown["width"] <= 2 * shown["rx"] - 20, shown
    browser.shot("page-graph-long-names.png")  # docs/img/ has a copy

    # Topics: /chatter has one subscriber (the talker itself). The page measures it through the daemon's web
    # node, which a page that connects meanwhile (a second tab) sees among the subscribers.
    browser.eval("document.querySelector(\"nav button[data-view='topics']\").click()")
    row = "document.querySelector(\"#topics tr[data-topic='/chatter']\")"
    browser.until(f"{row} && {row}.children[4].dataset.hz")
    second = browser.do("tab")
    browser.do("goto", url=url + "#topics", tab=second)
    browser.until("(mrosdPage.state.subs.get('/chatter') || new Set()).size >= 2", tab=second)
    browser.until(f"{row} && {row}.children[4].dataset.hz", tab=second)
    cells = browser.eval(f"[...{row}.children].map(td => td.textContent)", tab=second)
    assert cells[2:4] == ["1", "1"], cells

    browser.do("goto", url=url + "#log")
    browser.until("[...document.querySelectorAll('#log tr')].some(r => r.textContent.includes('talking'))")
    first = browser.eval(
        "(r => [r.children[0].textContent, r.children[0].title])"
        "([...document.querySelectorAll('#log tbody tr')].find(r => r.textContent.includes('talking')))"
    )
    assert re.fullmatch(r"\d\d:\d\d:\d\d\.\d{3}", first[0]), first
    assert re.search(r"\(\d{10}\.\d{9}\)$", first[1]), first
    browser.shot("page-log-times.png")  # docs/img/ has a copy
