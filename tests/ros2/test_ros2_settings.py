"""``[ros2]`` mode, distro, router and service_timeout -> options, and the status document's bounds (pure)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mrosd.config import parse_config
from mrosd.errors import ConfigError
from mrosd.ros2.options import ROUTER_LISTEN, ros2_options, zenoh_mode
from mrosd.ros2.status import MAX_ROWS, RateMeter, status_document


def test_defaults_are_listed_jazzy_and_a_client() -> None:
    opts = ros2_options(parse_config("").ros2, {})
    assert (opts.mode, opts.distro, opts.router, opts.humble, opts.service_timeout) == (
        "listed",
        "jazzy",
        False,
        False,
        10.0,
    )


def test_router_listens_where_rmw_zenohd_does_and_stops_connecting_to_itself() -> None:
    opts = ros2_options(parse_config("[ros2]\nrouter = true\n").ros2, {})
    assert opts.router and opts.listen == ROUTER_LISTEN == ("tcp/[::]:7447",) and opts.connect == ()
    opts = ros2_options(
        parse_config('[ros2]\nrouter = true\nlisten = ["tcp/0.0.0.0:7448"]\nconnect = ["tcp/up:7447"]\n').ros2, {}
    )
    assert opts.listen == ("tcp/0.0.0.0:7448",) and opts.connect == ("tcp/up:7447",)


def test_zenoh_mode_is_router_then_client_unless_listening() -> None:
    """router = true: the router; else a client of the router it dials, or a peer when it listens."""
    for toml, mode in (
        ("", "client"),
        ('listen = ["tcp/0.0.0.0:7448"]', "peer"),
        ("router = true", "router"),
        ('router = true\nlisten = ["tcp/0.0.0.0:7448"]', "router"),
    ):
        assert zenoh_mode(ros2_options(parse_config(f"[ros2]\n{toml}\n").ros2, {})) == mode, toml


def test_mapping_rules_and_share_trees_are_options(tmp_path: Path) -> None:
    rules = tmp_path / "rules.yaml"
    rules.write_text("- {ros1_package_name: a, ros2_package_name: b}\n")
    opts = ros2_options(parse_config(f'[ros2]\nmapping_rules = ["{rules}"]\nros2_share = ["/s"]\n').ros2, {})
    assert (opts.mapping_rules, opts.ros2_share) == ((str(rules),), ("/s",))
    rules.write_text("- {ros1_package_name: a}\n")
    with pytest.raises(ConfigError, match="rule 0"):
        ros2_options(parse_config(f'[ros2]\nmapping_rules = ["{rules}"]\n').ros2, {})


def test_mode_and_distro_are_checked() -> None:
    opts = ros2_options(parse_config('[ros2]\nmode = "demand"\ndistro = "humble"\n').ros2, {})
    assert opts.mode == "demand" and opts.humble
    for bad in ('mode = "some"', 'distro = "iron"', "service_timeout = 0"):
        with pytest.raises(ConfigError):
            parse_config(f"[ros2]\n{bad}\n")


def test_rates_come_from_two_samples_and_forget_gone_counters() -> None:
    meter = RateMeter()
    meter.sample(10.0, {"a": 0})
    meter.sample(12.0, {"a": 60, "b": 5})
    assert meter.rate("a") == 30.0 and meter.rate("b") == 0.0
    meter.sample(13.0, {"b": 6})
    assert meter.rate("a") == 0.0 and meter.rate("b") == 1.0


def test_the_status_document_is_bounded() -> None:
    rows = [{"topic": f"/t{i}"} for i in range(MAX_ROWS + 7)]
    doc = status_document(
        zid="z", domain_id=0, mode="all", distro="jazzy", router=False, to_ros2=rows, from_ros2=[], services=[]
    )
    assert len(doc["to_ros2"]) == MAX_ROWS and doc["to_ros2_more"] == 7 and "from_ros2_more" not in doc


def test_followed_ros2_subscribers_are_capped_and_forgotten_when_they_go() -> None:
    """Mode "demand" follows other sessions' ``MS`` tokens: a peer announcing endless topics is held at
    ``MAX_DEMANDED_TOPICS``, and a topic whose last subscriber goes is forgotten."""
    from typing import Any

    from mrosd.ros2 import inbound

    none: Any = None
    follower = inbound.Inbound(("/**",), 0, none, none, "ours", demand=True)
    for i in range(inbound.MAX_DEMANDED_TOPICS + 50):
        follower._remote_subscriber(f"/t{i}", f"key{i}", True)
    assert len(follower.remote_subscribers) == inbound.MAX_DEMANDED_TOPICS
    follower._remote_subscriber("/t0", "other", True)
    follower._remote_subscriber("/t0", "key0", False)
    assert follower.remote_subscribers["/t0"] == {"other"}
    follower._remote_subscriber("/t0", "other", False)
    assert "/t0" not in follower.remote_subscribers


def test_mros_ros2_status_prints_rates_services_and_what_was_left_out() -> None:
    from mros_cli.ros2 import format_status

    row = {"topic": "/chatter", "ros2_type": "std_msgs/msg/String", "key": "k", "sent": 40, "rate": 20.0}
    services = [
        {"service": "/set_flag", "direction": "to_ros2", "ros2_type": "std_srvs/srv/SetBool", "calls": 3}
        | {"errors": 1, "refused": 0, "problem": ""},
        {"service": "/odd", "direction": "from_ros2", "ros2_type": "", "calls": 0, "errors": 0, "refused": 0}
        | {"problem": "ros2: service /odd is not offered to ROS 2: unknown srv type"},
    ]
    doc = status_document(
        zid="z",
        domain_id=3,
        mode="demand",
        distro="humble",
        router=True,
        to_ros2=[row | {"dropped": 2, "latched": False, "problem": ""}] * (MAX_ROWS + 1),
        from_ros2=[],
        services=services,
    )
    text = format_status(doc)
    assert text.splitlines()[0] == "zenoh id z, domain 3, mode demand, humble, router"
    assert "  /chatter  std_msgs/msg/String  20 Hz  sent 40  dropped 2" in text
    assert "  ... and 1 more" in text
    assert "  /set_flag -> ROS 2  std_srvs/srv/SetBool  calls 3  errors 1  refused 0" in text
    assert "  /odd <- ROS 2  ros2: service /odd is not offered to ROS 2: unknown srv type" in text
