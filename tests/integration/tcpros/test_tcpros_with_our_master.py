"""Our nodes against mrosd's own master, in one event loop: registration, publisherUpdate, services."""

from __future__ import annotations

import mrosd
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


async def test_topics_and_services_work_through_mrosds_master() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("listener", master.uri) as b:
        sub = await b.subscribe("/chatter", String)
        async with node("talker", master.uri) as a:
            # The subscriber learns of the publisher through publisherUpdate from our master.
            pub = await a.advertise("/chatter", String)
            await sub.wait_for_publishers(1, timeout=10)
            await pub.wait_for_subscribers(1, timeout=10)
            await pub.publish(String(data="via mrosd master"))
            assert (await sub.next(timeout=5)).data == "via mrosd master"
            await a.advertise_service("/set", SetBool, lambda r: SetBool._response_class(success=r.data))
            resp = await b.service_proxy("/set", SetBool).call(SetBool._request_class(data=True))
            assert resp.success
        state = await b.master_call("getSystemState")
        assert not any(t == "/chatter" for t, _ in state[0])
