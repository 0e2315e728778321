"""rosbridge clients using service types that only ``ROS_PACKAGE_PATH`` defines, through ``mros bridge``.

As rosbridge_server finds a type it was never shown: a client advertises ``my_pkg/AddTwoInts`` and another
calls it, and a ROS node's ``my_pkg/Multiply`` service is called, while neither type exists anywhere but in
a package directory on the bridge process's ``ROS_PACKAGE_PATH`` (not in this test process, not in mrosd's
definitions). The clients are roslibpy processes; an unknown type's error must name it and every place
searched.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import json
import os
import re
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import pytest

import mrosd
from mrosd import backports
from mrosd.errors import MasterError, MsgNotFoundError
from mrosd.master import Master
from mrosd.msg import TypeStore, get_service_class
from tests.web.test_web_real_clients import NodeClient

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("roslibpy") is None, reason="roslibpy is not installed: pip install -e '.[dev]'"
)

SRVS = {
    "AddTwoInts": "int64 a\nint64 b\n---\nint64 sum\n",
    "Multiply": "# a product\nfloat64 x\nfloat64 y\n---\nfloat64 product\n",
}


def make_workspace(root: Path) -> Path:
    """``root/src/my_pkg`` (package.xml, srv/): what catkin's source space holds, found by walking it."""
    pkg = root / "src" / "my_pkg"
    (pkg / "srv").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package format='2'><name>my_pkg</name><version>0.0.1</version></package>\n")
    for name, text in SRVS.items():
        (pkg / "srv" / f"{name}.srv").write_text(text)
    return root


@contextlib.asynccontextmanager
async def bridge_process(master_uri: str, package_path: Path) -> AsyncIterator[str]:
    """``mros bridge`` in a process of its own with ``ROS_PACKAGE_PATH``; its rosbridge URL."""
    env = {
        **os.environ,
        "ROS_PACKAGE_PATH": str(package_path),
        "PYTHONPATH": f"{ROOT}:{ROOT / 'cli'}:{os.environ.get('PYTHONPATH', '')}",
    }
    argv = ["-m", "mros_cli.main", "--master-uri", master_uri, "bridge", "--port", "0", "--rosbridge-port", "0"]
    proc = await asyncio.create_subprocess_exec(
        sys.executable, *argv, env=env, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        assert proc.stderr is not None
        async with backports.timeout(30):
            line = (await proc.stderr.readline()).decode()
        match = re.search(r"rosbridge (ws://\S+/)", line)
        assert match, line
        yield match.group(1)
    finally:
        if proc.returncode is None:
            proc.kill()
        await proc.wait()


async def roslibpy_client(url: str) -> NodeClient:
    host, port = re.match(r"ws://([^:/]+):(\d+)/", url).groups()  # type: ignore[union-attr]
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        str(HERE / "roslibpy_services.py"),
        host,
        port,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        limit=1 << 20,
    )
    client = NodeClient(proc)
    await client.until("connected", timeout=30)
    return client


async def wait_for_service(node: mrosd.Node, name: str) -> None:
    async with backports.timeout(20):
        while True:
            try:
                await node.master.lookup_service(name)
                return
            except MasterError:
                await asyncio.sleep(0.05)


async def test_clients_provide_and_call_services_whose_types_only_ros_package_path_defines(
    master: Master, tmp_path: Path
) -> None:
    workspace = make_workspace(tmp_path / "ws")
    with pytest.raises(MsgNotFoundError):  # this process has never heard of it: only the bridge's path has it
        get_service_class("my_pkg/AddTwoInts")
    multiply = get_service_class("my_pkg/Multiply", TypeStore(ros_package_path=str(workspace)))
    clients: list[NodeClient] = []
    try:
        async with (
            bridge_process(master.uri, workspace) as url,
            mrosd.Node("calculator", master_uri=master.uri, argv=[], host="127.0.0.1") as calculator,
        ):
            await calculator.advertise_service(
                "/multiply", multiply, lambda r: multiply._response_class(product=r.x * r.y)
            )
            provider, caller = await roslibpy_client(url), await roslibpy_client(url)
            clients += [provider, caller]

            await provider.send(cmd="advertise", service="/add_two_ints", type="my_pkg/AddTwoInts")
            await provider.until("advertised")
            await wait_for_service(calculator, "/add_two_ints")
            await caller.send(cmd="call", service="/add_two_ints", args={"a": 40, "b": 2})
            assert (await caller.until("response", service="/add_two_ints"))["values"] == {"sum": 42}

            # A ROS node's service: the bridge reads its type from a probe, its definition from the path.
            await caller.send(cmd="call", service="/multiply", args={"x": 1.5, "y": 4.0}, retry=20)
            event = await caller.until("response", service="/multiply", timeout=30)
            assert event["values"] == {"product": 6.0}

            await caller.send(cmd="call", service="/rosapi/service_request_details", args={"type": "my_pkg/AddTwoInts"})
            details = (await caller.until("response", service="/rosapi/service_request_details"))["values"]
            assert details["typedefs"][0]["fieldnames"] == ["a", "b"]

            # An unknown type: the error names it and every place the bridge looked.
            await caller.send(cmd="call", service="/rosapi/service_request_details", args={"type": "nope_pkg/Nope"})
            error = (await caller.until("failed", service="/rosapi/service_request_details"))["error"]
            assert_names_every_place(error, "nope_pkg/Nope", workspace)
            async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws:
                await ws.send_str(json.dumps({"op": "advertise_service", "service": "/x", "type": "nope_pkg/Nope"}))
                status = json.loads((await ws.receive(timeout=10)).data)
                assert status["op"] == "status"
                assert status["level"] == "error"
                assert_names_every_place(status["msg"], "nope_pkg/Nope", workspace)
    finally:
        for client in clients:
            await client.close()


def assert_names_every_place(message: str, msg_type: str, workspace: Path) -> None:
    assert msg_type in message, message
    for place in ("mrosd's builtin definitions", f"ROS_PACKAGE_PATH={workspace}", "/usr/share", "/opt/ros/*/share"):
        assert place in message, (place, message)
