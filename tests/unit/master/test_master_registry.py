"""The pure registry: rosmaster's registration semantics and the notifications each change owes."""

from __future__ import annotations

from mrosd.master.registry import Registry

A = "http://127.0.0.1:1001/"
B = "http://127.0.0.1:1002/"
C = "http://127.0.0.1:1003/"


def test_register_publisher_returns_subscribers_and_notifies_them_with_the_new_publisher_list() -> None:
    r = Registry()
    pubs, notes = r.register_subscriber("/listener", "/chatter", "std_msgs/String", B)
    assert pubs == [] and notes == []
    subs, notes = r.register_publisher("/talker", "/chatter", "std_msgs/String", A)
    assert subs == [B]
    assert [(n.api, n.method, n.args) for n in notes] == [(B, "publisherUpdate", ("/chatter", [A]))]
    assert notes[0].coalesce == "/chatter"


def test_register_subscriber_returns_current_publishers() -> None:
    r = Registry()
    r.register_publisher("/talker", "/chatter", "std_msgs/String", A)
    pubs, _ = r.register_subscriber("/listener", "/chatter", "std_msgs/String", B)
    assert pubs == [A]


def test_unregister_publisher_only_matches_the_registered_api_and_notifies_subscribers() -> None:
    r = Registry()
    r.register_publisher("/talker", "/chatter", "std_msgs/String", A)
    r.register_subscriber("/listener", "/chatter", "std_msgs/String", B)
    assert r.unregister_publisher("/talker", "/chatter", C) == (0, [])
    n, notes = r.unregister_publisher("/talker", "/chatter", A)
    assert n == 1
    assert [(x.api, x.args) for x in notes] == [(B, ("/chatter", []))]
    assert r.lookup_node("/talker") is None  # no registrations left: the node is forgotten
    assert r.lookup_node("/listener") == B


def test_a_node_reregistering_with_a_new_api_replaces_the_old_one_and_shuts_it_down() -> None:
    r = Registry()
    r.register_publisher("/talker", "/chatter", "std_msgs/String", A)
    r.register_publisher("/talker", "/other", "std_msgs/String", A)
    r.register_subscriber("/listener", "/chatter", "std_msgs/String", C)
    _, notes = r.register_subscriber("/talker", "/x", "std_msgs/String", B)
    # As rosmaster: the old URI is told to shut down; the listener hears nothing until /chatter is re-registered.
    assert [(n.api, n.method) for n in notes] == [(A, "shutdown")]
    assert r.lookup_node("/talker") == B
    assert "/chatter" not in r.publishers and "/other" not in r.publishers


def test_shutdown_is_never_sent_to_an_api_that_now_belongs_to_another_node() -> None:
    r = Registry()
    r.register_publisher("/old", "/a", "std_msgs/String", A)
    r.register_publisher("/reuser", "/b", "std_msgs/String", A)  # the dead node's port was reused
    _, notes = r.register_publisher("/old", "/a", "std_msgs/String", B)
    assert not [n for n in notes if n.method == "shutdown"]
    assert r.lookup_node("/reuser") == A and r.lookup_node("/old") == B


def test_topic_type_is_set_by_the_last_publisher_and_only_by_a_subscriber_when_unknown() -> None:
    r = Registry()
    r.register_subscriber("/l", "/t", "pkg/Sub", B)
    assert r.topic_types["/t"] == "pkg/Sub"
    r.register_subscriber("/l2", "/t", "pkg/Other", C)
    assert r.topic_types["/t"] == "pkg/Sub"
    r.register_publisher("/p", "/t", "pkg/Pub", A)
    assert r.topic_types["/t"] == "pkg/Pub"
    r.register_publisher("/p2", "/t", "*", "http://127.0.0.1:9/")
    assert r.topic_types["/t"] == "pkg/Pub"


def test_services_have_one_provider_and_unregister_needs_the_current_service_api() -> None:
    r = Registry()
    r.register_service("/s1", "/srv", "rosrpc://h:1", A)
    r.register_service("/s2", "/srv", "rosrpc://h:2", B)
    assert r.lookup_service("/srv") == "rosrpc://h:2"
    assert r.unregister_service("/s1", "/srv", "rosrpc://h:1") == 0
    assert r.lookup_node("/s1") is None
    assert r.unregister_service("/s2", "/srv", "rosrpc://h:2") == 1
    assert r.lookup_service("/srv") is None


def test_published_topics_respect_the_subgraph_and_system_state_lists_everything() -> None:
    r = Registry()
    r.register_publisher("/p", "/ns/a", "pkg/A", A)
    r.register_publisher("/p", "/nsx/b", "pkg/B", A)
    r.register_subscriber("/s", "/ns/only_sub", "pkg/C", B)
    r.register_service("/p", "/srv", "rosrpc://h:1", A)
    assert r.published_topics("/ns") == [["/ns/a", "pkg/A"]]
    assert len(r.published_topics("")) == 2
    assert r.system_state() == [
        [["/ns/a", ["/p"]], ["/nsx/b", ["/p"]]],
        [["/ns/only_sub", ["/s"]]],
        [["/srv", ["/p"]]],
    ]


def test_the_version_changes_with_every_change_but_not_with_an_identical_registration() -> None:
    reg = Registry()
    v = reg.version
    reg.register_publisher("/n", "/t", "std_msgs/String", "http://a:1/")
    assert reg.version != v
    v = reg.version
    reg.register_publisher("/n", "/t", "std_msgs/String", "http://a:1/")
    reg.register_publisher("/n", "/t", "*", "http://a:1/")
    assert reg.version == v
    reg.register_publisher("/n", "/t", "std_msgs/Int32", "http://a:1/")  # type changes
    assert reg.version != v
    v = reg.version
    reg.register_publisher("/n", "/t", "std_msgs/Int32", "http://a:2/")  # node replaced
    assert reg.version != v
    v = reg.version
    reg.register_subscriber("/s", "/t", "*", "http://b:1/")
    assert reg.version != v
    v = reg.version
    reg.register_subscriber("/s", "/t", "std_msgs/Int32", "http://b:1/")
    assert reg.version == v
    reg.register_subscriber("/s", "/u", "*", "http://b:1/")
    assert reg.version != v
    v = reg.version
    reg.register_subscriber("/s", "/u", "std_msgs/String", "http://b:1/")  # type becomes known
    assert reg.version != v
    for change in (
        lambda: reg.unregister_subscriber("/s", "/u", "http://b:1/"),
        lambda: reg.register_service("/n", "/srv", "rosrpc://a:3", "http://a:2/"),
        lambda: reg.unregister_service("/n", "/srv", "rosrpc://a:3"),
        lambda: reg.subscribe_param("/n", "/p/", "http://a:2/"),
        lambda: reg.unsubscribe_param("/n", "/p/", "http://a:2/"),
        lambda: reg.unregister_publisher("/n", "/t", "http://a:2/"),
    ):
        v = reg.version
        change()
        assert reg.version != v
