"""The graph cleaner's pure parts: when a node counts as dead, and what removing it owes the graph."""

from __future__ import annotations

import itertools

from mrosd.master.api import MasterApi
from mrosd.master.cleanup import Probe, judge
from mrosd.master.registry import Registry

A = "http://127.0.0.1:1001/"
B = "http://127.0.0.1:1002/"


def test_only_a_refused_connection_confirmed_by_get_pid_makes_a_node_dead() -> None:
    assert judge(Probe.REFUSED, Probe.REFUSED, None, None)
    assert judge(Probe.REFUSED, Probe.REFUSED, None, 42)
    assert judge(Probe.REFUSED, Probe.ANSWERED, 7, 42)  # another process took the port
    assert not judge(Probe.REFUSED, Probe.ANSWERED, 42, 42)  # it answers: alive
    assert not judge(Probe.REFUSED, Probe.ANSWERED, 7, None)  # answers, nothing to compare with: alive
    assert not judge(Probe.REFUSED, Probe.ANSWERED, None, 42)  # answers without a pid: alive
    assert not judge(Probe.REFUSED, Probe.NO_ANSWER, None, 42)  # slow or stopped: never removed
    assert not judge(Probe.REFUSED, None, None, 42)
    for confirm, pid, known in itertools.product([*Probe, None], [None, 1, 2], [None, 1, 2]):
        assert not judge(Probe.ANSWERED, confirm, pid, known)
        assert not judge(Probe.NO_ANSWER, confirm, pid, known)


def test_removing_a_node_drops_all_its_registrations_and_updates_subscribers_of_its_topics() -> None:
    r = Registry()
    r.register_publisher("/dead", "/t", "std_msgs/String", A)
    r.register_publisher("/alive", "/t", "std_msgs/String", B)
    r.register_subscriber("/dead", "/in", "std_msgs/String", A)
    r.register_service("/dead", "/srv", "rosrpc://h:1", A)
    r.subscribe_param("/dead", "/p/", A)
    r.register_subscriber("/alive", "/t", "std_msgs/String", B)
    v = r.version
    notes = r.remove_node("/dead")
    assert [(n.api, n.method, n.args) for n in notes] == [(B, "publisherUpdate", ("/t", [B]))]
    assert r.lookup_node("/dead") is None and r.lookup_service("/srv") is None
    assert "/in" not in r.subscribers and "/p/" not in r.param_subscribers
    assert r.version != v
    assert r.remove_node("/dead") == []
    assert r.apis() == {B: ["/alive"]}


def test_every_registration_call_bumps_the_node_generation() -> None:
    r = Registry()
    r.register_publisher("/n", "/t", "std_msgs/String", A)
    entry = r.nodes["/n"]
    before = entry.generation
    r.register_publisher("/n", "/t", "std_msgs/String", A)  # identical: still proof of life
    assert entry.generation == before + 1


def test_the_cleaner_is_off_without_a_notifier_or_with_a_zero_interval() -> None:
    assert MasterApi(None).cleaner is None
    assert MasterApi(None, cleanup_interval=0).cleanup_interval == 0
