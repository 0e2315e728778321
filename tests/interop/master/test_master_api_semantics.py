"""Master API and Parameter Server semantics, each checked against Debian's rosmaster and ours in one test.

These cover the behaviours ros_comm's ``test_rosmaster`` suite (rosmaster.test, paramserver.test)
checks: registration bookkeeping and what getSystemState/lookupNode/getTopicTypes report, topic type
rules, argument validation codes, and the parameter server's name resolution, value types,
namespaces and search. Written from the Master API specification and checked against the real
rosmaster (``any_master`` runs each test on both), not copied from ros_comm.
"""

from __future__ import annotations

import datetime
import math
import xmlrpc.client
from typing import Any

import pytest

from tests.rosenv import needs_ros

pytestmark = needs_ros

Proxy = xmlrpc.client.ServerProxy
NODE_API = "http://localhost:4567/"
ME = "/semantics_test"


def ok(reply: Any) -> Any:
    code, status, value = reply
    assert code == 1, f"code {code}: {status}"
    return value


def error(reply: Any) -> None:
    assert len(reply) == 3
    assert reply[0] == -1, f"expected -1, got {reply}"


def test_get_pid_and_get_uri_answer_and_reject_a_missing_caller_id(m: Proxy) -> None:
    error(m.getPid())
    error(m.getUri())
    assert ok(m.getPid(ME)) > 0
    assert isinstance(ok(m.getUri(ME)), str)


def test_services_register_look_up_and_unregister_one_by_one(m: Proxy) -> None:
    node = "/service_node"
    for i in range(5):
        ok(m.registerService(node, f"/service-{i}", f"rosrpc://localhost:123{i}/", NODE_API))
        assert ok(m.lookupService(ME, f"/service-{i}")) == f"rosrpc://localhost:123{i}/"
        assert ok(m.lookupNode(ME, node)) == NODE_API
        srvs = ok(m.getSystemState(ME))[2]
        assert all([f"/service-{j}", [node]] in srvs for j in range(i + 1))
    for i in range(5):
        assert ok(m.unregisterService(node, f"/service-{i}", f"rosrpc://localhost:123{i}/")) == 1
        error(m.lookupService(ME, f"/service-{i}"))
        if i < 4:
            assert ok(m.lookupNode(ME, node)) == NODE_API  # still has services: still known
        srvs = ok(m.getSystemState(ME))[2]
        assert [s for s, _ in srvs] == [f"/service-{j}" for j in range(i + 1, 5)]
    error(m.lookupNode(ME, node))  # no stale node entry once its last registration is gone


@pytest.mark.parametrize("kind", ["Publisher", "Subscriber"])
def test_topics_register_and_unregister_with_node_and_type_bookkeeping(m: Proxy, kind: str) -> None:
    node = f"/{kind.lower()}_node"
    index = 0 if kind == "Publisher" else 1
    for i in range(5):
        ok(getattr(m, f"register{kind}")(node, f"/topic-{i}", "test_rosmaster/String", NODE_API))
        assert ok(m.lookupNode(ME, node)) == NODE_API
        assert [f"/topic-{i}", "test_rosmaster/String"] in ok(m.getTopicTypes(ME))
        published = ok(m.getPublishedTopics(ME, "/"))
        assert ([f"/topic-{i}", "test_rosmaster/String"] in published) == (kind == "Publisher")
        graph = ok(m.getSystemState(ME))[index]
        assert all([f"/topic-{j}", [node]] in graph for j in range(i + 1))
    for i in range(5):
        assert ok(getattr(m, f"unregister{kind}")(node, f"/topic-{i}", NODE_API)) == 1
        if i < 4:
            assert ok(m.lookupNode(ME, node)) == NODE_API
        graph = ok(m.getSystemState(ME))[index]
        assert [t for t, _ in graph] == [f"/topic-{j}" for j in range(i + 1, 5)]
    error(m.lookupNode(ME, node))


def test_register_publisher_returns_the_subscribers_in_registration_order(m: Proxy) -> None:
    subs = []
    for port in range(5678, 5683):
        api = f"http://localhost:{port}"
        subs.append(api)
        ok(m.registerSubscriber(f"/sub_node-{port}", "/pub_topic", "test_rosmaster/String", api))
        assert ok(m.registerPublisher("/pub_node", "/pub_topic", "test_rosmaster/String", NODE_API)) == subs


def test_a_star_type_is_reported_until_a_real_type_and_never_overwrites_one(m: Proxy) -> None:
    topic = "/type_test_pub_topic"
    assert ok(m.registerPublisher("/pub_node", topic, "*", NODE_API)) == []
    assert [topic, "*"] in ok(m.getPublishedTopics(ME, "/"))
    assert [topic, "*"] in ok(m.getTopicTypes(ME))
    for t in ["test_rosmaster/String", "*"]:
        assert ok(m.registerPublisher("/pub_node", topic, t, NODE_API)) == []
        assert [topic, "test_rosmaster/String"] in ok(m.getPublishedTopics(ME, "/"))
        assert [topic, "test_rosmaster/String"] in ok(m.getTopicTypes(ME))


def test_a_topic_with_only_a_star_typed_subscriber_is_in_no_type_list(m: Proxy) -> None:
    """rosmaster lets a subscriber set a topic's type only with a real type (master_api.registerSubscriber:
    "don't let '*' type squash valid typing"): a topic whose one registration is a ``*`` subscriber is in
    getSystemState but in neither getTopicTypes nor getPublishedTopics, until a real type comes."""
    topic = "/star_sub_topic"
    ok(m.registerSubscriber("/star_sub", topic, "*", NODE_API))
    assert [topic, ["/star_sub"]] in ok(m.getSystemState(ME))[1]
    assert topic not in [t for t, _ in ok(m.getTopicTypes(ME))]
    assert topic not in [t for t, _ in ok(m.getPublishedTopics(ME, "/"))]
    ok(m.registerSubscriber("/typed_sub", topic, "test_rosmaster/String", NODE_API))
    assert [topic, "test_rosmaster/String"] in ok(m.getTopicTypes(ME))


SRV, SRV_API, TOPIC, TYPE = "/service", "rosrpc://localhost:1234/", "/a_topic", "test_rosmaster/String"
INVALID_CALLS = [
    ("registerService", ()),
    ("registerService", (ME, SRV)),
    ("registerService", (ME, SRV, SRV_API)),
    ("registerService", (ME, "", SRV_API, NODE_API)),
    ("registerService", (ME, SRV, "", NODE_API)),
    ("registerService", (ME, SRV, SRV_API, "")),
    ("unregisterService", ()),
    ("unregisterService", (ME, SRV)),
    ("unregisterService", (ME, "", SRV_API)),
    ("unregisterService", (ME, SRV, "")),
    *[
        call
        for kind in ("Publisher", "Subscriber")
        for call in [
            (f"register{kind}", ()),
            (f"register{kind}", (ME, TOPIC)),
            (f"register{kind}", (ME, TOPIC, TYPE)),
            (f"register{kind}", (ME, "", TYPE, NODE_API)),
            (f"register{kind}", (ME, TOPIC, "", NODE_API)),
            (f"register{kind}", (ME, TOPIC, TYPE, "")),
            (f"unregister{kind}", ()),
            (f"unregister{kind}", (ME, TOPIC)),
            (f"unregister{kind}", (ME, "", NODE_API)),
            (f"unregister{kind}", (ME, TOPIC, "")),
        ]
    ],
]


def test_bad_arity_and_empty_arguments_answer_minus_one(m: Proxy) -> None:
    for method, args in INVALID_CALLS:
        reply = getattr(m, method)(*args)
        assert reply[0] == -1, f"{method}{args} -> {reply}"
    assert ok(m.getSystemState(ME)) == [[], [], []]  # nothing was registered by the bad calls


# --- parameter server -------------------------------------------------------------------------


def user_params(m: Proxy) -> list[str]:
    return sorted(n for n in ok(m.getParamNames("/")) if n not in ("/run_id", "/rosdistro", "/rosversion"))


def test_has_param_resolves_names_and_sees_namespaces_once_created(m: Proxy) -> None:
    assert not ok(m.hasParam("/node", "/new_param"))
    ok(m.setParam("/node", "/new_param", 1))
    assert ok(m.hasParam("/node", "/new_param"))
    assert ok(m.hasParam("/node", "new_param"))
    for key in ("/sub/sub2/new_param2", "/sub/sub2/", "/sub/sub2", "/sub/", "/sub"):
        assert not ok(m.hasParam("/node", key))
    ok(m.setParam("/node", "/sub/sub2/new_param2", 1))
    for key in ("/sub/sub2/new_param2", "/sub/sub2/", "/sub/sub2", "/sub/", "/sub", "sub/sub2/new_param2"):
        assert ok(m.hasParam("/node", key)), key
    assert ok(m.hasParam("/sub/node", "sub2/new_param2"))
    assert ok(m.hasParam("/sub/sub2/node", "new_param2"))
    assert ok(m.hasParam("/sub/node", "sub2"))
    assert ok(m.hasParam("/node", "sub"))


def test_get_param_resolves_names_and_returns_whole_namespaces(m: Proxy) -> None:
    error(m.getParam("/node", "/new_param"))
    ok(m.setParam("/node", "/new_param", 7))
    assert ok(m.getParam("/node", "new_param")) == 7
    ok(m.setParam("/node", "/sub/sub2/new_param2", 8))
    for caller, key in [
        ("/node", "sub/sub2/new_param2"),
        ("/sub/node", "sub2/new_param2"),
        ("/sub/sub2/node", "new_param2"),
        ("/foo/bar/baz/blah/node", "/sub/sub2/new_param2"),
    ]:
        assert ok(m.getParam(caller, key)) == 8
    for k, v in (("P", 1), ("I", 2), ("D", 3)):
        ok(m.setParam("/node", f"/ns/gains/{k}", v))
    pid = {"P": 1, "I": 2, "D": 3}
    assert ok(m.getParam("/node", "/ns/gains")) == pid
    assert ok(m.getParam("/node", "/ns/gains/")) == pid
    assert ok(m.getParam("/node", "/ns/")) == {"gains": pid}
    assert ok(m.getParam("/node", "/ns")) == {"gains": pid}
    everything = ok(m.getParam("/node", "/"))
    for launch_key in ("run_id", "roslaunch", "rosversion", "rosdistro"):
        everything.pop(launch_key, None)
    assert everything == {"new_param": 7, "sub": {"sub2": {"new_param2": 8}}, "ns": {"gains": pid}}
    # No searching down: a relative name is not looked up below the caller's namespace.
    ok(m.setParam("/down/one/two/three/node", "dparam1", 5))
    assert not ok(m.hasParam("/down/one/node", "dparam1"))
    error(m.getParam("/down/one/two/node", "dparam1"))


def test_set_param_changes_types_replaces_namespaces_and_keeps_an_empty_dict(m: Proxy) -> None:
    for v in ["a", {"a": "b"}, 1, 1.0, "foo", {"c": "d"}, 4]:
        ok(m.setParam("/node", "/multi/multi_param", v))
        assert ok(m.getParam("/node", "multi/multi_param")) == v
    pid = {"P": 1, "I": 2, "D": 3}
    ok(m.setParam("/node", "/gains", pid))
    assert ok(m.getParam("/node", "/gains")) == pid
    assert ok(m.getParam("/node", "/gains/D")) == 3
    subns = {"gains1": pid, "gains2": pid}
    ok(m.setParam("/node", "/ns", subns))
    assert ok(m.getParam("/node", "/ns/gains1/P")) == 1
    assert ok(m.getParam("/node", "/ns/")) == subns
    ok(m.setParam("/node", "/ns", {}))
    assert ok(m.hasParam("/node", "/ns/"))
    assert ok(m.getParam("/node", "/ns/")) == {}
    assert not ok(m.hasParam("/node", "/ns/gains1"))
    assert not ok(m.hasParam("/node", "/ns/gains1/P"))


VALUES: list[tuple[str, list[Any]]] = [
    ("int", [0, 1024, 2147483647, -2147483647]),
    ("boolean", [True, False]),
    ("unicode", ["", "hello", "Andr\u0082", "\ufeffAndr\u0082"]),
    ("ascii", [chr(n) for n in range(32, 128)]),
    ("string", ["", "x", "hello-there", "new\nline", "tab\t"]),
    ("double", [0.0, math.pi, -math.pi, 3.4028235e38, -3.4028235e38]),
    ("datetime", [datetime.datetime(2005, 12, 6, 12, 13, 14), datetime.datetime(1492, 12, 6, 12, 13, 14)]),
    ("base64", [xmlrpc.client.Binary(b""), xmlrpc.client.Binary(b"\0"), xmlrpc.client.Binary(bytes(range(255)))]),
    ("array", [[], [1, 2, 3], ["a", "b", "c"], [0.0, 0.1, -4.0], [1, "a", True], [[1, 2], ["a"], [1.0, 2.1]]]),
]


def test_every_xmlrpc_value_type_round_trips_in_every_scope_and_deletes_leave_no_names(m: Proxy) -> None:
    state: dict[str, Any] = {}
    for scope in ("", "/scope1", "/scope/sub1/sub2"):
        for kind, values in VALUES:
            for i, value in enumerate(values):
                ok(m.setParam(f"{scope}/node", f"{kind}-{i}", value))
                assert ok(m.hasParam(f"{scope}/node", f"{kind}-{i}"))
                state[f"{scope}/{kind}-{i}"] = value
    for key, value in state.items():
        got = ok(m.getParam("/", key))
        if isinstance(value, datetime.datetime):
            assert got == xmlrpc.client.DateTime(value), key
        elif isinstance(value, float):
            assert got == pytest.approx(value), key
        else:
            assert got == value, key
    assert user_params(m) == sorted(state)
    for key in list(state):
        ok(m.deleteParam("", key))
    assert user_params(m) == []


def test_relative_and_private_keys_resolve_against_the_caller(m: Proxy) -> None:
    expected: dict[str, int] = {}
    for i, ns in enumerate(("", "/en", "/en/sub1", "/en/sub1/sub2")):
        caller = f"{ns}/node"
        m.setParam(caller, "param1", 100 + i)
        expected[f"{ns}/param1"] = 100 + i
        assert ok(m.getParam("/", f"{ns}/param1")) == ok(m.getParam(caller, "param1")) == 100 + i
        assert ok(m.hasParam("node", f"{ns}/param1"))
        m.setParam(caller, "~private", 200 + i)
        expected[f"{caller}/private"] = 200 + i
        assert ok(m.getParam("/", f"{caller}/private")) == ok(m.getParam(caller, "~private")) == 200 + i
        m.setParam(caller, "altnode/param2", 300 + i)  # another node's private parameter, by relative name
        expected[f"{ns}/altnode/param2"] = 300 + i
        assert ok(m.getParam(f"{ns}/altnode", "~param2")) == 300 + i
        assert ok(m.hasParam(f"{ns}/altnode", "~param2"))
    assert user_params(m) == sorted(expected)


def test_search_param_walks_up_from_the_caller_and_matches_partial_keys(m: Proxy) -> None:
    def val(n: int) -> dict[str, Any]:
        return {"level1_p1": n, "level1_p2": {"level2_p2": n + 1}}

    ok(m.setParam("/root", "/param", val(1)))
    assert ok(m.searchParam("/root", "param")) == "/param"
    ok(m.setParam("/root", "/level1/param", val(2)))
    ok(m.setParam("/root", "/level1/level2/param", val(3)))
    ok(m.setParam("/root", "/level1/level2/level3/level4/param", val(4)))
    for caller, found in [
        ("/root", "/param"),
        ("/level1/node", "/level1/param"),
        ("/level1/level2/node", "/level1/level2/param"),
        ("/level1/level2/level3/node", "/level1/level2/param"),
        ("/level1/level2/level3/level4/node", "/level1/level2/level3/level4/param"),
        ("/not/level1/level2/level3/level4/node", "/param"),
    ]:
        assert ok(m.searchParam(caller, "param")) == found, caller
    for base, caller in [
        ("/param", "/not/level1/level2/level3/level4/node"),
        ("/level1/param", "/level1/notlevel2/notlevel3/node"),
        ("/level1/level2/param", "/level1/level2/notlevel3/notlevel3/node"),
        ("/level1/level2/level3/level4/param", "/level1/level2/level3/level4/l5/l6/node"),
    ]:
        assert ok(m.searchParam(caller, "param/level1_p1")) == base + "/level1_p1"
        key = base + "/level1_p2/level2_p2"
        ok(m.deleteParam(caller, key))  # the search matches on the head ("param") only
        assert ok(m.searchParam(caller, "param/level1_p2/level2_p2")) == key
        assert ok(m.searchParam(caller, "param/non_existent")) == base + "/non_existent"
        assert ok(m.searchParam(caller, "param/level1_p2/non_existent")) == base + "/level1_p2/non_existent"
    error(m.searchParam("/root", "no_such_param"))
