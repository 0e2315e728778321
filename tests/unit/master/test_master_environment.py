"""How the standalone master picks its port and advertised host from the ROS environment."""

from __future__ import annotations

import socket

import pytest

from mrosd.master.__main__ import parse_args
from mrosd.master.server import advertised_host, parse_networks, port_from_master_uri


def test_the_port_comes_from_ros_master_uri_or_defaults_to_11311() -> None:
    assert port_from_master_uri("http://robot:11411/") == 11411
    assert port_from_master_uri("http://robot/") == 11311
    assert port_from_master_uri(None) == 11311
    assert port_from_master_uri("http://robot:notaport/") == 11311


def test_the_advertised_host_prefers_ros_hostname_then_ros_ip_then_the_bind_address() -> None:
    assert advertised_host("0.0.0.0", {"ROS_HOSTNAME": "robot.local", "ROS_IP": "10.0.0.2"}) == "robot.local"
    assert advertised_host("0.0.0.0", {"ROS_IP": "10.0.0.2"}) == "10.0.0.2"
    assert advertised_host("127.0.0.1", {}) == "127.0.0.1"
    # a wildcard bind address is never advertised: other hosts could not dial it
    assert advertised_host("0.0.0.0", {}) == (socket.gethostname() or "localhost")
    assert advertised_host("::", {}) == (socket.gethostname() or "localhost")


def test_allow_lists_accept_networks_and_single_addresses_and_reject_garbage() -> None:
    nets = parse_networks(["127.0.0.0/8", "::1", "10.1.2.3"])
    assert [str(n) for n in nets] == ["127.0.0.0/8", "::1/128", "10.1.2.3/32"]
    with pytest.raises(ValueError):
        parse_networks(["not-a-network"])


def test_command_line_options_parse() -> None:
    args = parse_args(["--port", "12000", "--allow", "127.0.0.0/8", "--host", "127.0.0.1"])
    assert (args.port, args.allow, args.host) == (12000, ["127.0.0.0/8"], "127.0.0.1")


def test_a_bad_allow_network_is_a_clean_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    from mrosd.master.__main__ import main

    assert main(["--allow", "nonsense", "--port", "0"]) == 2
    assert "bad --allow" in capsys.readouterr().err
