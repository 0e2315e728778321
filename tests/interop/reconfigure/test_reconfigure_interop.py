"""mrosd.reconfigure and ``mros reconfigure`` against Debian's dynamic_reconfigure both ways, with its own
TestConfig server."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.reconfigure import (
    Description,
    EnumConstant,
    GroupSpec,
    Param,
    ReconfigureClient,
    ReconfigureError,
    ReconfigureServer,
)
from tests.interop.cli.cliutil import mros
from tests.rosenv import PROJECT_ROOT, ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

SCRIPT = str(Path(__file__).resolve().parents[2] / "data" / "reconfigure" / "dr_node.py")


def has_dynamic_reconfigure() -> bool:
    probe = subprocess.run(
        [ROS_PYTHON, "-c", "import dynamic_reconfigure.client"], capture_output=True, timeout=60, check=False
    )
    return probe.returncode == 0


pytestmark = [
    needs_ros,
    pytest.mark.skipif(not has_dynamic_reconfigure(), reason="python3-dynamic-reconfigure is not installed"),
]


async def start_test_server(procs: Processes, master: str) -> None:
    server = procs.start([ROS_PYTHON, SCRIPT, "server"], ros_env(master, procs.tmp), stderr=subprocess.DEVNULL)
    assert await asyncio.to_thread(lambda: list(iter_lines_until(server, 1, 30.0))) == ["up"]


async def debian_client(procs: Processes, master: str, *args: str) -> dict[str, Any]:
    done = await asyncio.to_thread(
        subprocess.run,
        [ROS_PYTHON, SCRIPT, *args],
        env=ros_env(master, procs.tmp),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


async def test_mros_reconfigure_set_changes_int_on_the_test_config_server(procs: Processes, rosmaster: str) -> None:
    await start_test_server(procs, rosmaster)
    listed = await asyncio.to_thread(mros, rosmaster, procs.tmp, "reconfigure", "list")
    assert "/dr_server" in listed.stdout.split(), listed
    got = await asyncio.to_thread(mros, rosmaster, procs.tmp, "reconfigure", "get", "/dr_server")
    assert "int_: 0" in got.stdout.splitlines() and 'str_: "foo"' in got.stdout.splitlines(), got

    done = await asyncio.to_thread(mros, rosmaster, procs.tmp, "reconfigure", "set", "/dr_server", "int_", "7")
    assert done.returncode == 0, done
    assert (await debian_client(procs, rosmaster, "get", "/dr_server"))["int_"] == 7

    done = await asyncio.to_thread(
        mros, rosmaster, procs.tmp, "reconfigure", "set", "/dr_server", "{double_: 1.5, str_: hi, bool_: true}"
    )
    assert done.returncode == 0, done
    config = await debian_client(procs, rosmaster, "get", "/dr_server")
    assert (config["double_"], config["str_"], config["bool_"]) == (1.5, "hi", True)

    refused = await asyncio.to_thread(mros, rosmaster, procs.tmp, "reconfigure", "set", "/dr_server", "int_", "99")
    assert refused.returncode == 1 and "out of its range [-10, 10]" in refused.stderr, refused
    unknown = await asyncio.to_thread(mros, rosmaster, procs.tmp, "reconfigure", "set", "/dr_server", "nope", "1")
    assert unknown.returncode == 1 and "don't know parameter: nope" in unknown.stderr, unknown


async def test_our_client_reads_the_test_config_description_and_sets_an_enum(procs: Processes, rosmaster: str) -> None:
    await start_test_server(procs, rosmaster)
    async with (
        mrosd.Node("dr_client", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ReconfigureClient(node, "/dr_server") as client,
    ):
        description = await client.get_description()
        assert [g.name for g in description.groups][:1] == ["Default"]
        int_ = description.param("int_")
        assert int_ is not None and (int_.type, int_.min, int_.max, int_.default) == ("int", -10, 10, 0)
        enum = description.param("int_enum_")
        assert enum is not None and [c.name for c in enum.enum][:2] == ["Small", "Medium"]
        config = await client.update_configuration({"int_enum_": "Medium", "group1_int": 5})
        assert (config["int_enum_"], config["group1_int"]) == (1, 5)
        with pytest.raises(ReconfigureError, match="out of its range"):
            await client.update_configuration({"double_": 11.0})
    config = await debian_client(procs, rosmaster, "get", "/dr_server")
    assert (config["int_enum_"], config["group1_int"]) == (1, 5)


async def test_debian_client_drives_our_server_and_sees_its_adjustments(procs: Processes, rosmaster: str) -> None:
    description = Description(
        [
            GroupSpec(
                "Default",
                0,
                params=[
                    Param("gain", "double", 1.0, min=0.0, max=10.0, level=1, description="Gain"),
                    Param("steps", "int", 3, min=0, max=100, level=2),
                    Param("name", "str", "cam", level=4),
                    Param("enabled", "bool", True, level=8),
                    Param("mode", "int", 0, min=0, max=2, enum=(EnumConstant("Low", 0), EnumConstant("High", 2))),
                ],
            ),
            GroupSpec("Advanced", 1, parent=0, params=[Param("offset", "double", 0.0, min=-1.0, max=1.0)]),
        ]
    )
    levels: list[int] = []

    def callback(config: dict[str, Any], level: int) -> dict[str, Any]:
        levels.append(level)
        config["steps"] = config["steps"] - config["steps"] % 2  # the server adjusts: even steps only
        return config

    async with (
        mrosd.Node("our_dr", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ReconfigureServer(node, description, callback),
    ):
        config = await debian_client(procs, rosmaster, "set", "/our_dr", json.dumps({"gain": 2.5, "steps": 7}))
        assert (config["gain"], config["steps"], config["name"], config["enabled"]) == (2.5, 6, "cam", True)
        config = await debian_client(procs, rosmaster, "set", "/our_dr", json.dumps({"gain": 50.0, "mode": "High"}))
        assert (config["gain"], config["mode"]) == (10.0, 2)  # clamped to max, as dynamic_reconfigure's server
        config = await debian_client(procs, rosmaster, "get", "/our_dr")
        assert (config["gain"], config["steps"], config["offset"]) == (10.0, 6, 0.0)
        assert await node.get_param("/our_dr/steps") == 6
    assert levels[0] == 0xFFFFFFFF and levels[1] == 1 | 2


async def test_the_example_server_answers_debian_client_with_its_adjusted_value(
    procs: Processes, rosmaster: str
) -> None:
    example = procs.start(
        [sys.executable, str(PROJECT_ROOT / "examples" / "reconfigure_server.py")],
        ros_env(rosmaster, procs.tmp),
        stderr=subprocess.DEVNULL,
    )
    await asyncio.to_thread(lambda: list(iter_lines_until(example, 1, 30.0)))  # the first callback's line
    config = await debian_client(procs, rosmaster, "set", "/camera", json.dumps({"exposure": 22, "mode": "Roi"}))
    assert (config["exposure"], config["mode"], config["name"]) == (20, 2, "camera")
