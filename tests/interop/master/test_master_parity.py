"""Master API details where mrosd once differed from rosmaster, checked against both masters in one test.

Each test runs twice (``any_master``: Debian's rosmaster, then ours) with the same expectations, so
the expected behaviour is the real one. Callbacks are observed with recording slave APIs.
"""

from __future__ import annotations

import xmlrpc.client
from typing import Any

from tests.interop.master.conftest import RecordingSlave
from tests.rosenv import needs_ros

pytestmark = needs_ros


def ok(reply: Any) -> Any:
    code, status, value = reply
    assert code == 1, status
    return value


def test_get_param_names_lists_leaves_only_after_a_namespace_is_emptied(m: xmlrpc.client.ServerProxy) -> None:
    ok(m.setParam("/c", "/nsx/leaf", 1))
    ok(m.setParam("/c", "/keep/a", 2))
    assert sorted(ok(m.getParamNames("/c"))) == ["/keep/a", "/nsx/leaf"]
    ok(m.deleteParam("/c", "/nsx/leaf"))
    assert ok(m.getParamNames("/c")) == ["/keep/a"]
    assert ok(m.hasParam("/c", "/nsx"))  # the namespace itself still exists, empty
    assert ok(m.getParam("/c", "/nsx")) == {}
    ok(m.setParam("/c", "/empty", {}))  # an empty dict is a namespace, never a name
    assert ok(m.getParamNames("/c")) == ["/keep/a"]


def publisher_updates(calls: list[tuple[str, tuple[Any, ...]]], topic: str) -> list[list[str]]:
    return [list(args[2]) for method, args in calls if method == "publisherUpdate" and args[1] == topic]


def test_a_node_re_registering_under_a_new_uri_sends_exactly_what_rosmaster_sends(
    m: xmlrpc.client.ServerProxy, make_slave: Any
) -> None:
    sub: RecordingSlave = make_slave()
    old: RecordingSlave = make_slave()
    new: RecordingSlave = make_slave()
    sentinel: RecordingSlave = make_slave()
    ok(m.registerSubscriber("/sub", "/t", "std_msgs/String", sub.uri))
    ok(m.registerSubscriber("/sub", "/sentinel", "std_msgs/String", sub.uri))
    ok(m.registerPublisher("/node", "/t", "std_msgs/String", old.uri))
    ok(m.registerPublisher("/node", "/t_only_old", "std_msgs/String", old.uri))
    sub.wait_for(lambda calls: publisher_updates(calls, "/t") == [[old.uri]])

    # The node restarts under a new URI and first registers something else: the old node's
    # registrations vanish, its URI is told to shut down, and subscribers hear nothing yet.
    ok(m.registerSubscriber("/node", "/other", "std_msgs/String", new.uri))
    assert ok(m.lookupNode("/c", "/node")) == new.uri
    pubs, subs, _ = ok(m.getSystemState("/c"))
    assert ["/t_only_old", ["/node"]] not in pubs
    assert ["/other", ["/node"]] in subs
    ok(m.registerPublisher("/node", "/t", "std_msgs/String", new.uri))
    ok(m.registerPublisher("/sentinel_node", "/sentinel", "std_msgs/String", sentinel.uri))
    calls = sub.wait_for(lambda calls: publisher_updates(calls, "/sentinel") != [])
    assert publisher_updates(calls, "/t") == [[old.uri], [new.uri]]  # no publisherUpdate('/t', [])
    assert [m for m, _ in calls] == ["publisherUpdate"] * 3
    shutdown = old.wait_for(lambda calls: any(m == "shutdown" for m, _ in calls))
    assert [(m, args[0]) for m, args in shutdown] == [("shutdown", "/master")]
    assert new.calls == []
