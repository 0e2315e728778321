"""A service is called in each direction through ``Ros2Bridge``, against Debian's rosmaster, rospy and
``rosservice``, and zenoh-ros2-sdk's service server and client (an rmw_zenoh peer we did not write)."""

from __future__ import annotations

import asyncio
import subprocess
from pathlib import Path
from typing import Any

import pytest

from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.keys import EntityKind, parse_token
from mrosd.ros2.srvtypes import service_mapping
from mrosd.ros2.types import TypeMapper
from tests.ros2.test_ros2_interop import _tokens
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [pytest.mark.interop, needs_ros]
zenoh = pytest.importorskip("zenoh")
sdk = pytest.importorskip("zenoh_ros2_sdk")

SETBOOL_HASH = "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a"

SERVER = """
import rospy
from std_srvs.srv import SetBool, SetBoolResponse
rospy.init_node("flag_server")
rospy.Service("/set_flag", SetBool, lambda req: SetBoolResponse(success=req.data, message="rospy got %s" % req.data))
rospy.spin()
"""


def test_service_hashes_are_rmw_zenohs() -> None:
    """Known answer from rmw_zenoh's design document, and zenoh-ros2-sdk's hash of std_srvs/srv/SetBool."""
    mapper = TypeMapper()
    add = service_mapping(mapper, "example_interfaces/AddTwoInts", "int64 a\nint64 b\n", "int64 sum\n")
    assert add.type_hash == "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    from zenoh_ros2_sdk.utils import compute_service_type_hash

    setbool = service_mapping(mapper, "std_srvs/SetBool", "bool data\n", "bool success\nstring message\n")
    assert setbool.type_hash == SETBOOL_HASH
    assert compute_service_type_hash("std_srvs/srv/SetBool", "bool data", "bool success\nstring message") == (
        SETBOOL_HASH
    )


@pytest.fixture
def srv_messages(messages_dir: Path) -> Path:
    folder = messages_dir / "std_srvs" / "srv"
    folder.mkdir(parents=True)
    (folder / "SetBool.srv").write_text("bool data\n---\nbool success\nstring message\n")
    return messages_dir


async def test_a_service_is_called_in_each_direction(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, srv_messages: Path
) -> None:
    from zenoh_ros2_sdk import ROS2ServiceClient, ROS2ServiceServer
    from zenoh_ros2_sdk.session import ZenohSession

    options = Ros2Options(
        domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/set_flag",), from_ros2=("/ros2_flag",)
    )
    seen: list[Any] = []

    def on_request(req: Any) -> Any:
        seen.append(req.data)
        return server.response_msg_class(success=not req.data, message="ROS 2 got it")

    entities: list[Any] = []
    try:
        server = await asyncio.to_thread(
            ROS2ServiceServer,
            service_name="/ros2_flag",
            srv_type="std_srvs/srv/SetBool",
            callback=on_request,
            domain_id=0,
            router_ip="127.0.0.1",
            router_port=router,
        )
        entities.append(server)
        assert server.type_hash == SETBOOL_HASH
        async with Ros2Bridge(options, rosmaster) as bridge:
            env = ros_env(rosmaster, tmp_path)
            procs.python(SERVER, env)

            def ready() -> bool:
                services = bridge.services
                assert services is not None
                offered = services.offered.get("/set_flag")
                provided = services.provided.get("/ros2_flag")
                return (
                    offered is not None
                    and offered.token is not None
                    and provided is not None
                    and provided.service is not None
                )

            await bridge.wait_until(ready, 30)

            # ROS 2 -> ROS 1: zenoh-ros2-sdk's client calls the rospy server
            client = await asyncio.to_thread(
                ROS2ServiceClient,
                service_name="/set_flag",
                srv_type="std_srvs/srv/SetBool",
                domain_id=0,
                router_ip="127.0.0.1",
                router_port=router,
                timeout=10.0,
            )
            entities.append(client)
            response = await asyncio.to_thread(client.call, data=True)
            assert response is not None
            assert (response.success, response.message) == (True, "rospy got True")

            # ROS 1 -> ROS 2: Debian's rosservice calls zenoh-ros2-sdk's server
            call = await asyncio.to_thread(
                subprocess.run,
                ["rosservice", "call", "/ros2_flag", "data: false"],
                env=env,
                capture_output=True,
                timeout=30,
            )
            assert call.returncode == 0, call.stderr
            out = call.stdout.decode()
            assert "success: True" in out and "ROS 2 got it" in out, out
            assert seen == [False]

            parsed = [parse_token(t) for t in await asyncio.to_thread(_tokens, router)]
            ours = {(t.kind, t.topic): t for t in parsed if t.node == "mrosd_ros2"}
            ss = ours[(EntityKind.SERVICE, "/set_flag")]
            assert (ss.type_name, ss.type_hash) == ("std_srvs::srv::dds_::SetBool_", SETBOOL_HASH)
            assert ss.qos is not None and ss.qos.depth == 10
            assert (EntityKind.CLIENT, "/ros2_flag") in ours
            rows = {r["service"]: r for r in bridge.services.status()}  # type: ignore[union-attr]
            assert rows["/set_flag"]["calls"] == 1 and rows["/ros2_flag"]["calls"] == 1
            assert bridge.summary().endswith("2 service(s)")
    finally:
        for entity in entities:
            entity.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()


RULES = """
- ros1_package_name: std_srvs
  ros1_service_name: SetBool
  ros2_package_name: robot_interfaces
  ros2_service_name: Toggle
  request_fields_1_to_2: {data: enable}
  response_fields_1_to_2: {success: ok}
"""
TOGGLE = ("bool enable", "bool ok\nstring message")


def test_a_service_mapping_rule_renames_the_type_and_its_fields() -> None:
    """A service rule gives the ROS 2 name and field names, hashed as zenoh-ros2-sdk hashes the ROS 2 .srv."""
    from zenoh_ros2_sdk.utils import compute_service_type_hash

    from mrosd.ros2.mapping import parse_mapping_rules
    from mrosd.ros2.srvtypes import ros1_service_for, ros2_service_for

    mapper = TypeMapper(parse_mapping_rules(RULES))
    assert ros2_service_for(mapper, "std_srvs/SetBool") == "robot_interfaces/srv/Toggle"
    assert ros1_service_for(mapper, "robot_interfaces/srv/Toggle") == "std_srvs/SetBool"
    assert ros1_service_for(mapper, "std_srvs/srv/Trigger") == "std_srvs/Trigger"
    toggle = service_mapping(mapper, "std_srvs/SetBool", "bool data\n", "bool success\nstring message\n")
    assert (toggle.ros2_type, toggle.request_type) == (
        "robot_interfaces/srv/Toggle",
        "robot_interfaces/srv/Toggle_Request",
    )
    assert toggle.type_hash == compute_service_type_hash("robot_interfaces/srv/Toggle", *TOGGLE)
    assert [name for name, _ in mapper.store.fielddefs[toggle.response_type][1]] == ["ok", "message"]


async def test_a_renamed_service_type_is_called_in_each_direction(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, srv_messages: Path
) -> None:
    """ROS 1's std_srvs/SetBool is ROS 2's robot_interfaces/srv/Toggle through a service rule, both ways."""
    from zenoh_ros2_sdk import ROS2ServiceClient, ROS2ServiceServer
    from zenoh_ros2_sdk.session import ZenohSession

    folder = srv_messages / "robot_interfaces" / "srv"
    folder.mkdir(parents=True)
    (folder / "Toggle.srv").write_text(f"{TOGGLE[0]}\n---\n{TOGGLE[1]}\n")
    rules = tmp_path / "rules.yaml"
    rules.write_text(RULES)
    options = Ros2Options(
        domain_id=0,
        connect=(f"tcp/127.0.0.1:{router}",),
        to_ros2=("/set_flag",),
        from_ros2=("/ros2_toggle",),
        mapping_rules=(str(rules),),
    )
    entities: list[Any] = []
    try:
        server = await asyncio.to_thread(
            ROS2ServiceServer,
            service_name="/ros2_toggle",
            srv_type="robot_interfaces/srv/Toggle",
            callback=lambda req: server.response_msg_class(ok=not req.enable, message="toggled"),
            domain_id=0,
            router_ip="127.0.0.1",
            router_port=router,
        )
        entities.append(server)
        async with Ros2Bridge(options, rosmaster) as bridge:
            env = ros_env(rosmaster, tmp_path)
            procs.python(SERVER, env)

            def ready() -> bool:
                services = bridge.services
                assert services is not None
                offered = services.offered.get("/set_flag")
                provided = services.provided.get("/ros2_toggle")
                return offered is not None and offered.token is not None and provided is not None

            await bridge.wait_until(ready, 30)
            client = await asyncio.to_thread(
                ROS2ServiceClient,
                service_name="/set_flag",
                srv_type="robot_interfaces/srv/Toggle",
                domain_id=0,
                router_ip="127.0.0.1",
                router_port=router,
                timeout=10.0,
            )
            entities.append(client)
            response = await asyncio.to_thread(client.call, enable=True)
            assert response is not None
            assert (response.ok, response.message) == (True, "rospy got True")
            call = await asyncio.to_thread(
                subprocess.run,
                ["rosservice", "call", "/ros2_toggle", "data: false"],
                env=env,
                capture_output=True,
                timeout=30,
            )
            assert call.returncode == 0, call.stderr
            assert "success: True" in call.stdout.decode() and "toggled" in call.stdout.decode()
    finally:
        for entity in entities:
            entity.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()
