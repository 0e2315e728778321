"""MasterClient against Debian's real rosmaster: every call, success and failure codes."""

from __future__ import annotations

import pytest

from mrosd.errors import MasterError, MasterUnreachableError
from mrosd.master.client import MasterClient
from tests.rosenv import free_port, needs_ros

pytestmark = needs_ros

API = "http://127.0.0.1:1/"


async def test_registration_calls_round_trip_against_rosmaster(rosmaster: str) -> None:
    async with MasterClient(rosmaster, "/talker") as talker, MasterClient(rosmaster, "/listener") as listener:
        assert await talker.register_publisher("/chatter", "std_msgs/String", "http://127.0.0.1:2/") == []
        pubs = await listener.register_subscriber("/chatter", "std_msgs/String", "http://127.0.0.1:3/")
        assert pubs == ["http://127.0.0.1:2/"]
        assert await talker.lookup_node("/listener") == "http://127.0.0.1:3/"
        assert ("/chatter", "std_msgs/String") in await talker.get_published_topics("")
        assert ("/chatter", "std_msgs/String") in await talker.get_topic_types()
        await talker.register_service("/add", "rosrpc://127.0.0.1:4", "http://127.0.0.1:2/")
        assert await listener.lookup_service("/add") == "rosrpc://127.0.0.1:4"
        pubs_s, subs_s, srvs_s = await talker.get_system_state()
        assert ("/chatter", ["/talker"]) in pubs_s
        assert ("/chatter", ["/listener"]) in subs_s
        assert ("/add", ["/talker"]) in srvs_s
        assert await talker.get_uri() == rosmaster
        assert await talker.unregister_service("/add", "rosrpc://127.0.0.1:4") == 1
        assert await listener.unregister_subscriber("/chatter", "http://127.0.0.1:3/") == 1
        assert await talker.unregister_publisher("/chatter", "http://127.0.0.1:2/") == 1
        assert await talker.unregister_publisher("/chatter", "http://127.0.0.1:2/") == 0


async def test_failure_codes_raise_master_error_with_code_and_status(rosmaster: str) -> None:
    async with MasterClient(rosmaster, "/probe") as c:
        with pytest.raises(MasterError) as info:
            await c.lookup_node("/nobody")
        assert info.value.code == -1 and info.value.method == "lookupNode"
        with pytest.raises(MasterError):
            await c.lookup_service("/nothing")
        with pytest.raises(MasterError):
            await c.get_param("/not/set")


async def test_parameter_calls_round_trip_against_rosmaster(rosmaster: str) -> None:
    async with MasterClient(rosmaster, "/ns/node") as c:
        await c.set_param("/ns/gains", {"p": 1.5, "i": 0})
        assert await c.get_param("/ns/gains") == {"p": 1.5, "i": 0}
        assert await c.has_param("/ns/gains/p")
        assert not await c.has_param("/ns/gains/d")
        assert "/ns/gains/p" in await c.get_param_names()
        assert await c.search_param("gains") == "/ns/gains"
        assert await c.search_param("absent_everywhere") is None
        assert await c.subscribe_param(API, "/ns/gains") == {"p": 1.5, "i": 0}
        assert await c.unsubscribe_param(API, "/ns/gains") == 1
        await c.delete_param("/ns/gains")
        assert not await c.has_param("/ns/gains")


async def test_a_dead_master_uri_raises_master_unreachable_error() -> None:
    async with MasterClient(f"http://127.0.0.1:{free_port()}/", "/probe", timeout=2.0) as c:
        with pytest.raises(MasterUnreachableError):
            await c.get_uri()
