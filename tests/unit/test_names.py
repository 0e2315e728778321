"""ROS names (mrosd.names): the strict rules, checked against the ROS wiki Names page, and the lenient master rules."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import InvalidNameError
from mrosd.names import (
    NodeNames,
    canonicalize,
    is_valid_name,
    lenient_namespace_of,
    lenient_resolve,
    namespace_of,
    parse_argv,
    resolve,
)


@pytest.mark.parametrize(
    ("node", "name", "expected"),
    [
        ("/node1", "bar", "/bar"),
        ("/node1", "/bar", "/bar"),
        ("/node1", "~bar", "/node1/bar"),
        ("/wg/node2", "bar", "/wg/bar"),
        ("/wg/node2", "/bar", "/bar"),
        ("/wg/node2", "~bar", "/wg/node2/bar"),
        ("/wg/node3", "foo/bar", "/wg/foo/bar"),
        ("/wg/node3", "~foo/bar", "/wg/node3/foo/bar"),
    ],
)
def test_the_wiki_resolution_table_holds(node: str, name: str, expected: str) -> None:
    assert resolve(name, node) == expected


def test_invalid_names_are_refused() -> None:
    for bad in ("", "1abc", "a b", "a//b", "a-b", "~"):
        assert not is_valid_name(bad)
        with pytest.raises(InvalidNameError):
            resolve(bad, "/n")


def test_canonicalize_and_namespace() -> None:
    assert canonicalize("/a/b/") == "/a/b"
    assert canonicalize("/") == "/"
    assert namespace_of("/a/b") == "/a/"
    assert namespace_of("/a") == "/"


def test_argv_splits_special_args_remaps_and_the_rest() -> None:
    special, remaps, rest = parse_argv(["__name:=x", "chatter:=/talk", "_rate:=5", "plain"])
    assert special == {"__name": "x"}
    assert remaps == {"chatter": "/talk"}
    assert rest == ["plain"]


def test_node_names_come_from_argv_then_the_environment() -> None:
    n = NodeNames.from_argv("talker", [], {"ROS_NAMESPACE": "/robot"})
    assert (n.name, n.namespace) == ("/robot/talker", "/robot/")
    n = NodeNames.from_argv("talker", ["__ns:=/other", "__name:=t2"], {"ROS_NAMESPACE": "/robot"})
    assert n.name == "/other/t2"
    n = NodeNames.from_argv("talker", [], {"ROS_NAMESPACE": "relative"})
    assert n.name == "/relative/talker"


def test_remaps_are_resolved_in_the_nodes_namespace() -> None:
    n = NodeNames.from_argv("talker", ["chatter:=talk", "~x:=/y"], {"ROS_NAMESPACE": "/r"})
    assert n.remappings == {"/r/chatter": "/r/talk", "/r/talker/x": "/y"}
    assert n.resolve("chatter") == "/r/talk"
    assert n.resolve("/r/chatter") == "/r/talk"
    assert n.resolve("~x") == "/y"
    assert n.resolve("other") == "/r/other"


def test_a_bad_node_name_or_namespace_is_refused() -> None:
    with pytest.raises(InvalidNameError):
        NodeNames.from_argv("bad name", [], {})
    with pytest.raises(InvalidNameError):
        NodeNames.from_argv("ok", ["__ns:=bad ns"], {})


part = st.from_regex(r"[A-Za-z][A-Za-z0-9_]{0,5}", fullmatch=True)


@given(st.lists(part, min_size=1, max_size=4), st.lists(part, min_size=1, max_size=4))
def test_resolved_names_are_global_canonical_and_valid(node_parts: list[str], name_parts: list[str]) -> None:
    node = "/" + "/".join(node_parts)
    for name in ("/".join(name_parts), "/" + "/".join(name_parts), "~" + "/".join(name_parts)):
        out = resolve(name, node)
        assert out.startswith("/")
        assert is_valid_name(out)
        assert canonicalize(out) == out


@given(st.text(alphabet="/ab~_", max_size=14))
def test_canonicalize_leaves_no_empty_part_and_keeps_the_parts(name: str) -> None:
    out = canonicalize(name)
    assert canonicalize(out) == out
    assert "//" not in out
    assert out == "/" or not out.endswith("/")
    assert [p for p in out.split("/") if p] == [p for p in name.split("/") if p]
    assert out.startswith("/") == name.startswith("/")


def test_lenient_master_rules_differ_from_the_strict_node_rules_where_rosmaster_does() -> None:
    # rosmaster resolves what callers send without validating it; a node's own names are checked.
    assert lenient_resolve("", "/ns/node") == "/ns/"
    assert lenient_resolve("x", "relative_caller") == "/x"
    assert lenient_resolve("9bad", "/ns/node") == "/ns/9bad"
    with pytest.raises(InvalidNameError):
        resolve("9bad", "/ns/node")
    assert lenient_namespace_of("/a//b") == "/a//"
    assert namespace_of("/a//b") == "/a/"
    assert lenient_namespace_of("relative") == "/"


@given(st.text(alphabet="/ab~", max_size=10), st.sampled_from(["/ns/node", "/node", "/a/b/c"]))
def test_lenient_and_strict_resolution_agree_on_legal_names(name: str, node: str) -> None:
    if is_valid_name(name) and name not in ("/", "~"):
        assert lenient_resolve(name, node) == resolve(name, node)
