"""Two robots over TLS endpoints with certificates made here; a robot without the fleet's CA cannot link."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path

import pytest

from mrosd.msg import get_message_class
from tests.fleet.fleetenv import first_across, fleet

pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")
String = get_message_class("std_msgs/String")


def make_ca_and_cert(where: Path, name: str) -> dict[str, str]:
    """A CA and a certificate it signed for localhost/127.0.0.1 (openssl), as the [fleet] tls_* settings."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    where.mkdir()

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=where, check=True, capture_output=True, timeout=60)

    run(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "1",
        "-subj",
        f"/CN={name}-ca",
    )
    run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "robot.key", "-out", "robot.csr", "-subj", "/CN=localhost")
    (where / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    run(
        "x509",
        "-req",
        "-in",
        "robot.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-out",
        "robot.pem",
        "-days",
        "1",
        "-extfile",
        "ext.cnf",
    )
    return {
        "tls_root_ca": str(where / "ca.pem"),
        "tls_certificate": str(where / "robot.pem"),
        "tls_private_key": str(where / "robot.key"),
    }


async def test_topic_crosses_a_tls_link(tmp_path: Path) -> None:
    tls = make_ca_and_cert(tmp_path / "fleet", "fleet")
    async with fleet("robot1", "robot2", transport="tls", **tls) as (r1, r2), r1.node("t") as a, r2.node("l") as b:
        pub = await a.advertise("/chatter", String)
        pub.publish_nowait(String(data="over tls"))
        assert (await first_across(r2, "/robot1/chatter", String, pub, String(data="over tls"), b)).data == "over tls"
        assert r2.bridge.status()["peers"]


async def test_a_robot_with_another_ca_does_not_link(tmp_path: Path) -> None:
    ours = make_ca_and_cert(tmp_path / "fleet", "fleet")
    theirs = make_ca_and_cert(tmp_path / "stranger", "stranger")
    async with (
        fleet("robot1", transport="tls", **ours) as (r1,),
        fleet("robot9", transport="tls", connect_to=r1.endpoint, **theirs) as (r9,),
    ):
        await asyncio.sleep(2)  # several connection attempts (retried at most 1 s apart)
        assert r1.bridge.status()["peers"] == [] and r9.bridge.status()["peers"] == []


async def test_knowing_the_ca_without_a_certificate_is_not_enough(tmp_path: Path) -> None:
    ours = make_ca_and_cert(tmp_path / "fleet", "fleet")
    async with (
        fleet("robot1", transport="tls", **ours) as (r1,),
        fleet("robot9", connect_to=r1.endpoint, tls_root_ca=ours["tls_root_ca"]) as (r9,),
    ):
        await asyncio.sleep(2)  # several connection attempts (retried at most 1 s apart)
        assert r1.bridge.status()["peers"] == [] and r9.bridge.status()["peers"] == []
