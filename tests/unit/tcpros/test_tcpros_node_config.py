"""Node identity and addresses come from arguments, argv and the environment, in rospy's order."""

from __future__ import annotations

import mrosd


def test_the_environment_gives_master_host_and_namespace() -> None:
    env = {"ROS_MASTER_URI": "http://m:1/", "ROS_HOSTNAME": "robot.local", "ROS_IP": "10.0.0.1", "ROS_NAMESPACE": "/r"}
    n = mrosd.Node("talker", argv=[], environ=env)
    assert (n.master_uri, n.host, n.name) == ("http://m:1/", "robot.local", "/r/talker")


def test_ros_ip_is_used_when_no_hostname_is_set_and_ipv6_is_kept_exact() -> None:
    n = mrosd.Node("talker", argv=[], environ={"ROS_IP": "fe80::1"})
    assert n.host == "fe80::1"
    assert n._format_host() == "[fe80::1]"
    assert n._bind_host == "::"


def test_argv_overrides_the_environment_and_remaps_names() -> None:
    env = {"ROS_MASTER_URI": "http://m:1/", "ROS_HOSTNAME": "a"}
    n = mrosd.Node(
        "talker",
        argv=["__name:=other", "__ns:=/ns", "__master:=http://x:2/", "__ip:=127.0.0.2", "chatter:=/c"],
        environ=env,
    )
    assert (n.name, n.master_uri, n.host) == ("/ns/other", "http://x:2/", "127.0.0.2")
    assert n.resolve_name("chatter") == "/c"
    assert n.resolve_name("~p") == "/ns/other/p"


def test_an_explicit_master_uri_and_host_win() -> None:
    n = mrosd.Node("t", master_uri="http://y:3/", argv=[], host="h", environ={"ROS_MASTER_URI": "http://m:1/"})
    assert (n.master_uri, n.host) == ("http://y:3/", "h")
