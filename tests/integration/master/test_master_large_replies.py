"""Replies far over one socket read (64 KiB) from our master and from Debian's rosmaster, read by our client.

The same calls go to both masters in the same test: multi-megabyte parameters (a URDF-sized string, a 5 MB
string, a big dict) and a graph of thousands of topics (getSystemState, getTopicTypes, getPublishedTopics).
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import AsyncIterator

import pytest

from mrosd.master import Master
from mrosd.xmlrpc import XmlRpcClient
from tests.rosenv import needs_ros

pytestmark = needs_ros

TOPICS = 3000


@pytest.fixture
async def ours() -> AsyncIterator[str]:
    # no sweep: the graph's nodes are at a port nothing listens on, and a loaded machine's mros calls can come
    # after the 5 s sweep has rightly removed them all (rosmaster, the reference, keeps them)
    async with Master("127.0.0.1", 0, advertise="127.0.0.1", cleanup_interval=0) as m:
        yield m.uri


def urdf_like(size: int) -> str:
    link = '<link name="link_{i}"><visual><geometry><mesh filename="package://robot/meshes/l{i}.stl"/></geometry></visual></link>\n'
    out = ['<?xml version="1.0"?>\n<robot name="big">\n']
    i = 0
    while sum(map(len, out)) < size:
        out.append(link.format(i=i))
        i += 1
    out.append("</robot>\n")
    return "".join(out)


async def test_multi_megabyte_parameters_round_trip_on_both_masters(ours: str, rosmaster: str) -> None:
    values = {
        "/robot_description": urdf_like(300_000),
        "/blob": "x" * 5_000_000,
        "/tree": {f"k{i}": {"name": f"joint_{i}", "limits": [i, -i, 0.5 * i]} for i in range(20_000)},
    }
    async with XmlRpcClient(timeout=60) as client:
        for uri in (ours, rosmaster):
            for key, value in values.items():
                assert (await client.call(uri, "setParam", "/cli", key, value))[0] == 1
            for key, value in values.items():
                code, _, got = await client.call(uri, "getParam", "/cli", key)
                assert code == 1 and got == value, (uri, key)
            code, _, whole = await client.call(uri, "getParam", "/cli", "/")
            assert code == 1 and whole["robot_description"] == values["/robot_description"], uri


async def test_a_graph_of_thousands_of_topics_is_listed_on_both_masters(ours: str, rosmaster: str) -> None:
    async with XmlRpcClient(timeout=60) as client:
        for uri in (ours, rosmaster):
            for start in range(0, TOPICS, 500):
                calls = [
                    {
                        "methodName": "registerPublisher",
                        "params": [
                            f"/node_{i}",
                            f"/robot/sensors/topic_{i:05d}",
                            "std_msgs/String",
                            f"http://127.0.0.1:1/{i}",
                        ],
                    }
                    for i in range(start, start + 500)
                ]
                results = await client.call(uri, "system.multicall", calls)
                assert all(r[0][0] == 1 for r in results)
            code, _, (pubs, _, _) = await client.call(uri, "getSystemState", "/cli")
            assert code == 1 and sum(t.startswith("/robot/sensors/") for t, _ in pubs) == TOPICS, uri
            code, _, types = await client.call(uri, "getTopicTypes", "/cli")
            assert code == 1 and sum(t.startswith("/robot/sensors/") for t, _ in types) == TOPICS, uri
            code, _, published = await client.call(uri, "getPublishedTopics", "/cli", "")
            assert code == 1 and len(published) >= TOPICS, uri


def mros(uri: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


async def test_mros_reads_a_urdf_and_a_1500_topic_graph_from_both_masters(ours: str, rosmaster: str) -> None:
    urdf = urdf_like(300_000)
    outputs = []
    async with XmlRpcClient(timeout=60) as client:
        for uri in (ours, rosmaster):
            assert (await client.call(uri, "setParam", "/cli", "/robot_description", urdf))[0] == 1
            calls = [
                {
                    "methodName": "registerPublisher",
                    "params": [f"/n{i}", f"/big/t{i:04d}", "std_msgs/String", "http://127.0.0.1:1/"],
                }
                for i in range(1500)
            ]
            assert all(r[0][0] == 1 for r in await client.call(uri, "system.multicall", calls))
    for uri in (ours, rosmaster):
        got = await asyncio.to_thread(mros, uri, "param", "get", "/robot_description")
        assert got.returncode == 0, got.stderr
        assert urdf.splitlines()[2] in got.stdout
        topics = await asyncio.to_thread(mros, uri, "topic", "list")
        assert topics.returncode == 0, topics.stderr
        assert sum(line.startswith("/big/t") for line in topics.stdout.splitlines()) == 1500
        outputs.append((got.stdout, topics.stdout))
    assert outputs[0] == outputs[1]
