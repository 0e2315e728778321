"""permessage-deflate is negotiated on both web ports: a client's compressed frame that inflates past the frame
limit (a deflate bomb: 8 MiB of zeros is 8 KiB on the wire) is refused at the limit, before the authentication
of a rosbridge client too, and costs nobody else anything."""

from __future__ import annotations

import aiohttp

from mrosd.master import Master
from mrosd.web.access import AccessPolicy
from mrosd.web.handshake import AUTH_FRAME
from mrosd.web.server import WebServer

MAX_FRAME = 1024 * 1024
BOMB = "\0" * (8 * MAX_FRAME)


async def test_a_deflate_bomb_is_refused_at_the_frame_limit_on_both_ports(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", max_frame=MAX_FRAME) as server,
        aiohttp.ClientSession() as http,
    ):
        fox = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], compress=15)
        rosbridge = await http.ws_connect(server.rosbridge_url, compress=15)
        assert fox.compress and rosbridge.compress, "permessage-deflate was not negotiated"
        for ws in (fox, rosbridge):
            await ws.send_str(BOMB)
            while (msg := await ws.receive(timeout=10)).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                pass
            assert ws.close_code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG, (ws.close_code, msg)
        # the server serves the next client as before
        again = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], compress=15)
        assert (await again.receive_json(timeout=10))["op"] == "serverInfo"
        await again.close()


async def test_before_its_auth_op_a_rosbridge_client_cannot_inflate_past_the_auth_frame_limit(master: Master) -> None:
    async with (
        WebServer(
            master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", policy=AccessPolicy(token="t0ken")
        ) as server,
        aiohttp.ClientSession() as http,
    ):
        ws = await http.ws_connect(server.rosbridge_url, compress=15)
        assert ws.compress
        await ws.send_str('{"op": "auth", "mac": "' + "a" * (4 * AUTH_FRAME) + '"}')
        while (await ws.receive(timeout=10)).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
            pass
        assert ws.close_code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG
