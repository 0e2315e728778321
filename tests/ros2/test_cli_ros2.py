"""``mros ros2 bridge`` against Debian's rosmaster: it announces its node to ROS 2 and stops on Ctrl-C."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mrosd import backports
from mrosd.ros2.keys import EntityKind, parse_token
from tests.ros2.test_ros2_interop import _tokens
from tests.rosenv import Processes, needs_ros

pytestmark = [needs_ros]
pytest.importorskip("zenoh")


def test_without_topics_it_is_a_usage_error() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "ros2", "bridge"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 2 and "--to-ros2" in done.stderr


async def test_mros_ros2_bridge_announces_its_node_and_stops_on_ctrl_c(
    procs: Processes, rosmaster: str, router: int, tmp_path: Path
) -> None:
    proc = procs.our_python(
        [
            "-m",
            "mros_cli.main",
            "--master-uri",
            rosmaster,
            "ros2",
            "bridge",
            "--to-ros2",
            "/chatter",
            "--connect",
            f"tcp/127.0.0.1:{router}",
            "--domain-id",
            "5",
        ]
    )
    async with backports.timeout(30):
        while not any(
            t.kind is EntityKind.NODE and t.node == "mrosd_ros2" and t.domain_id == 5
            for t in map(parse_token, await asyncio.to_thread(_tokens, router))
        ):
            assert proc.poll() is None, proc.communicate()
            await asyncio.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _out, err = await asyncio.to_thread(proc.communicate, None, 20)
    assert proc.returncode in (0, 130), err
    assert b"Traceback" not in err


async def test_mros_ros2_status_lists_the_bridged_topic(
    procs: Processes, rosmaster: str, router: int, tmp_path: Path
) -> None:
    import mrosd
    from mrosd.msg import get_message_class
    from mrosd.ros2.bridge import Ros2Bridge, Ros2Options

    String = get_message_class("std_msgs/String")
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/chatter",))
    async with (
        Ros2Bridge(options, rosmaster) as bridge,
        mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
    ):
        pub = await node.advertise("/chatter", String)
        msg = String()
        msg.data = "hi"

        def sent() -> bool:
            bt = bridge.topics.get("/chatter")
            return bt is not None and bt.rmw is not None and bt.rmw.sent > 0

        async with backports.timeout(30):
            while not sent():
                await pub.publish(msg)
                await asyncio.sleep(0.1)
        done = await asyncio.to_thread(
            subprocess.run,
            [sys.executable, "-m", "mros_cli.main", "--master-uri", rosmaster, "ros2", "status"],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
    assert done.returncode == 0, done.stderr
    assert "/chatter  std_msgs/msg/String  " in done.stdout and " Hz  sent " in done.stdout


def test_mros_ros2_status_without_a_bridge_is_one_error_line(rosmaster: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", rosmaster, "ros2", "status"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 1 and "no ros2 bridge" in done.stderr and "Traceback" not in done.stderr


async def test_mros_ros2_bridge_with_tls_flags_refuses_a_session_without_a_certificate_and_links_one_with(
    procs: Processes, tmp_path: Path
) -> None:
    """``--tls-root-ca``, ``--tls-certificate`` and ``--tls-private-key`` (the ``[ros2]`` keys' names) on a
    ``tls/`` listen endpoint: a session that knows the CA but shows no certificate cannot link; one with a
    certificate of that CA links, and its publisher's token makes the bridge publish the topic on ROS 1."""
    import xmlrpc.client

    import zenoh

    from mrosd.master import Master
    from mrosd.ros2.keys import dds_type_name, mangle_name
    from mrosd.ros2.types import TypeMapper
    from tests.fleet.test_fleet_tls import make_ca_and_cert
    from tests.rosenv import free_port

    tls = make_ca_and_cert(tmp_path / "pki", "robots")
    endpoint = f"tls/127.0.0.1:{free_port()}"

    def session(keys: dict[str, str]) -> zenoh.Session:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        for key, value in keys.items():
            conf.insert_json5(f"transport/link/tls/{key}", f'"{value}"')
        if "connect_certificate" in keys:
            conf.insert_json5("transport/link/tls/enable_mtls", "true")
        return zenoh.open(conf)

    def publishers(uri: str) -> dict[str, list[str]]:
        with xmlrpc.client.ServerProxy(uri) as api:
            _code, _msg, (pubs, _subs, _srvs) = api.getSystemState("/probe")
        return {str(topic): list(nodes) for topic, nodes in pubs}

    async with Master(host="127.0.0.1", port=0) as master:
        proc = procs.our_python(
            [
                "-m",
                "mros_cli.main",
                "--master-uri",
                master.uri,
                "ros2",
                "bridge",
                "--router",
                "--listen",
                endpoint,
                "--from-ros2",
                "/chatter",
                "--domain-id",
                "0",
                "--tls-root-ca",
                tls["tls_root_ca"],
                "--tls-certificate",
                tls["tls_certificate"],
                "--tls-private-key",
                tls["tls_private_key"],
            ]
        )
        assert proc.stderr is not None  # the line it prints once started: its listener is up
        line = await asyncio.wait_for(asyncio.to_thread(proc.stderr.readline), 30)
        assert b"Ctrl-C to stop" in line, line + (proc.stderr.read() if proc.poll() is not None else b"")
        with pytest.raises(zenoh.ZError):  # no link to any endpoint
            await asyncio.to_thread(session, {"root_ca_certificate": tls["tls_root_ca"]})
        laptop = await asyncio.to_thread(
            session,
            {
                "root_ca_certificate": tls["tls_root_ca"],
                "connect_certificate": tls["tls_certificate"],
                "connect_private_key": tls["tls_private_key"],
            },
        )
        try:
            type_hash = TypeMapper().mapping("std_msgs/String").type_hash
            zid = str(laptop.zid())
            key = (
                f"@ros2_lv/0/{zid}/0/1/MP/%/%/talker/{mangle_name('/chatter')}/"
                f"{dds_type_name('std_msgs/msg/String')}/{type_hash}/::,:,:,:,,"
            )
            token = laptop.liveliness().declare_token(key)
            async with backports.timeout(20):
                while "/mrosd_ros2" not in (await asyncio.to_thread(publishers, master.uri)).get("/chatter", []):
                    assert proc.poll() is None
                    await asyncio.sleep(0.1)
            token.undeclare()
        finally:
            await asyncio.to_thread(laptop.close)
        proc.send_signal(signal.SIGINT)
        _out, err = await asyncio.to_thread(proc.communicate, None, 20)
        assert b"Traceback" not in err
