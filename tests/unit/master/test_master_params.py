"""The pure parameter tree and paramUpdate computation, with rosmaster's rules."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.master.params import ParamTree, param_updates

A = "http://127.0.0.1:1001/"
B = "http://127.0.0.1:1002/"
C = "http://127.0.0.1:1003/"


def test_dict_values_replace_a_whole_subtree() -> None:
    t = ParamTree()
    t.set("/a/old", 1)
    t.set("/a", {"x": 1, "sub": {"y": 2}})
    assert t.get("/a") == {"x": 1, "sub": {"y": 2}}
    assert not t.has("/a/old")
    assert t.get("/a/sub/y") == 2
    assert sorted(t.names()) == ["/a/sub/y", "/a/x"]


def test_names_lists_leaves_only_never_an_emptied_or_empty_namespace() -> None:
    t = ParamTree()
    t.set("/nsx/leaf", 1)
    t.set("/keep", {"a": 2, "empty": {}})
    t.delete("/nsx/leaf")
    assert t.has("/nsx")
    assert t.names() == ["/keep/a"]


def test_setting_below_a_scalar_turns_it_into_a_namespace() -> None:
    t = ParamTree()
    t.set("/a", 5)
    t.set("/a/b", 6)
    assert t.get("/a") == {"b": 6}


def test_delete_removes_subtrees_and_missing_keys_raise() -> None:
    t = ParamTree()
    t.set("/a/b/c", 1)
    t.delete("/a/b")
    assert t.get("/a") == {}
    with pytest.raises(KeyError):
        t.delete("/a/b")
    with pytest.raises(KeyError):
        t.delete("/")
    with pytest.raises(KeyError):
        t.get("/a/b/c")


def test_root_can_only_be_set_to_a_dict() -> None:
    t = ParamTree()
    t.set("/", {"x": 1})
    assert t.get("/") == {"x": 1}
    with pytest.raises(TypeError):
        t.set("/", 3)


def test_search_looks_in_the_private_namespace_then_each_parent() -> None:
    t = ParamTree()
    t.set("/robot_description", "root")
    t.set("/pr2/robot_description", "pr2")
    assert t.search("/pr2/foo", "robot_description") == "/pr2/robot_description"
    assert t.search("/pr2/foo", "robot_description/arm") == "/pr2/robot_description/arm"
    assert t.search("/other/node", "robot_description") == "/robot_description"
    t.set("/pr2/foo/robot_description", "private")
    assert t.search("/pr2/foo", "robot_description") == "/pr2/foo/robot_description"
    assert t.search("/x", "missing") is None
    assert t.search("/x", "/robot_description") == "/robot_description"
    assert t.search("/x", "/nothing") is None
    with pytest.raises(ValueError):
        t.search("/x", "~private")


def test_subscribers_of_the_key_and_its_parents_get_the_new_value() -> None:
    subs = {"/a/b/": {"/n1": A}, "/a/": {"/n2": B}, "/z/": {"/n3": C}}
    notes = param_updates(subs, "/a/b", 5)
    assert sorted((n.api, n.args) for n in notes) == [(A, ("/a/b/", 5)), (B, ("/a/b/", 5))]


def test_subscribers_below_a_written_namespace_get_their_sub_values_or_empty_dicts() -> None:
    subs = {"/a/b/": {"/n1": A}, "/a/gone/": {"/n2": B}}
    notes = param_updates(subs, "/a", {"b": 7})
    assert sorted((n.api, n.args) for n in notes) == [(A, ("/a/b/", 7)), (B, ("/a/gone/", {}))]


def test_deleting_a_namespace_tells_subscribers_below_it_with_empty_dicts() -> None:
    notes = param_updates({"/a/b/": {"/n1": A}}, "/a", {})
    assert [(n.api, n.args) for n in notes] == [(A, ("/a/b/", {}))]


def test_the_caller_is_not_told_about_its_own_change() -> None:
    notes = param_updates({"/a/": {"/me": A, "/other": B}}, "/a", 1, ignore_node="/me")
    assert [n.api for n in notes] == [B]


NAMES = st.sampled_from(["a", "b", "c", "x1", "y_2"])
values = st.recursive(
    st.one_of(st.integers(-(2**31), 2**31 - 1), st.text(max_size=5), st.booleans(), st.floats(allow_nan=False)),
    lambda inner: st.dictionaries(NAMES, inner, max_size=3),
    max_leaves=10,
)
keys = st.lists(NAMES, min_size=1, max_size=3).map(lambda p: "/" + "/".join(p))


@given(st.lists(st.tuples(keys, values), max_size=8))
def test_the_last_value_set_at_a_key_is_what_get_returns(ops: list[tuple[str, Any]]) -> None:
    t = ParamTree()
    for key, value in ops:
        t.set(key, value)
        assert t.get(key) == value
        assert t.has(key)
        for name in t.names():
            assert t.has(name)
