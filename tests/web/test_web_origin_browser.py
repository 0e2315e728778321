"""Issue 31 case 1 in real headless Chromium: a page from another site tries both WebSocket ports of a daemon
with the default configuration (loopback, no token) and publishes Twists on /cmd_vel; a real subscriber counts
what arrives. The page's own origin and clients without an ``Origin`` (Python here) still connect and publish.
"""

from __future__ import annotations

import asyncio
import contextlib
import http.server
import json
import os
import shutil
import subprocess
import threading
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from tests.rosenv import Processes
from tests.web.webdaemon import CmdVelCounter, WebDaemon

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))

pytestmark = pytest.mark.skipif(
    NODE is None or not (HERE / "node_modules" / "playwright-core").is_dir() or not CHROMIUM.exists(),
    reason="node, chromium or playwright-core missing: scripts/install-system-deps.sh, "
    "then `npm ci --prefix tests/web`",
)

#: Opens one socket from the page it runs in and, if it opens, publishes ``n`` Twists on ``topic`` over it
#: (rosbridge: advertise + publish ops; Foxglove: a client channel + messageData frames), 50 ms apart.
ATTACK = """async (attempts) => {
  const results = [];
  for (const attempt of attempts) results.push(await one(attempt));
  return results;
  async function one({url, protocol, n, topic}) {
  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
  const ws = await new Promise((resolve) => {
    let s;
    try { s = protocol === "foxglove" ? new WebSocket(url, ["foxglove.websocket.v1"]) : new WebSocket(url); }
    catch (e) { resolve(null); return; }
    const t = setTimeout(() => resolve(null), 5000);
    s.onopen = () => { clearTimeout(t); resolve(s); };
    s.onclose = () => { clearTimeout(t); resolve(null); };
  });
  if (ws === null) return { open: false, sent: 0 };
  let sent = 0;
  if (protocol === "foxglove") {
    ws.send(JSON.stringify({ op: "advertise", channels: [
      { id: 7, topic, encoding: "ros1", schemaName: "geometry_msgs/Twist", schema: "" }] }));
    await sleep(300);
    for (let i = 0; i < n && ws.readyState === 1; i++) {
      const frame = new Uint8Array(5 + 48);
      const view = new DataView(frame.buffer);
      frame[0] = 1;
      view.setUint32(1, 7, true);
      view.setFloat64(5, 0.5, true);
      ws.send(frame); sent++; await sleep(50);
    }
  } else {
    ws.send(JSON.stringify({ op: "advertise", topic, type: "geometry_msgs/Twist" }));
    await sleep(300);
    for (let i = 0; i < n && ws.readyState === 1; i++) {
      ws.send(JSON.stringify({ op: "publish", topic, msg: { linear: { x: 0.5 } } }));
      sent++; await sleep(50);
    }
  }
  ws.close();
  return { open: true, sent };
  }
}"""


class _Page(http.server.BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        body = b"<!doctype html><title>cat pictures</title><p>nothing to see here</p>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: Any) -> None:
        pass


@pytest.fixture
def foreign_site() -> Iterator[int]:
    """Another web site on this machine (another port; reached as attacker.test too): its port."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield int(server.server_address[1])
    server.shutdown()
    server.server_close()


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebDaemon]:
    tmp = tmp_path_factory.mktemp("origin")
    procs = Processes(tmp)
    run = WebDaemon(procs, tmp)
    yield run
    run.close()
    procs.close()


def attack(page: str, attempts: list[tuple[str, str, int, str]]) -> tuple[str, str, Any]:
    """A job for ``browse``: open ``page`` and run ``ATTACK`` for each (socket URL, protocol, Twists, topic)."""
    arg = [{"url": url, "protocol": protocol, "n": n, "topic": topic} for url, protocol, n, topic in attempts]
    return page, ATTACK, arg


def browse(jobs: list[tuple[str, str, Any]]) -> list[tuple[int, Any]]:
    """Open each job's page in one Chromium (a fresh context each) and run its async function on its argument:
    the page's HTTP status and the function's result, per job."""
    assert NODE is not None
    out = subprocess.run(
        [NODE, str(HERE / "origin_browser.mjs"), json.dumps([{"url": u, "expr": e, "arg": a} for u, e, a in jobs])],
        capture_output=True,
        timeout=120,
        check=True,
        cwd=HERE,
    )
    replies: list[dict[str, Any]] = json.loads(out.stdout.decode().strip().splitlines()[-1])
    assert len(replies) == len(jobs) and not [r for r in replies if "error" in r], replies
    return [(r["status"], r["result"]) for r in replies]


def test_a_foreign_page_cannot_open_either_socket_and_nothing_reaches_cmd_vel(
    daemon: WebDaemon, foreign_site: int
) -> None:
    fox, ros = daemon.foxglove_port, daemon.rosbridge_port
    refused = {"open": False, "sent": 0}
    with CmdVelCounter(daemon.uri) as counter:
        jobs = [
            attack(
                page,
                [
                    (f"ws://{target}:{port}/", protocol, 5, "/cmd_vel")
                    for protocol, port in (("rosbridge", ros), ("foxglove", fox))
                    for target in (host, "127.0.0.1", "localhost")
                ],
            )
            for page, host in (
                (f"http://attacker.test:{foreign_site}/", "attacker.test"),
                (f"http://127.0.0.1:{foreign_site}/", "127.0.0.1"),
            )
        ]
        # DNS rebinding: attacker.test now resolves to the robot, so the attacker's page shares the daemon's
        # port; the Host it sends names the attacker's domain.
        rebound = [(f"ws://attacker.test:{ros}/", "rosbridge", 5, "/cmd_vel")]
        rebound.append((f"ws://attacker.test:{fox}/", "foxglove", 5, "/cmd_vel"))
        jobs.append(attack(f"http://attacker.test:{fox}/", rebound))
        replies = browse(jobs)
        for (page, _, arg), (_, results) in zip(jobs, replies, strict=True):
            assert results == [refused] * len(arg), (page, list(zip(arg, results, strict=True)))
        assert replies[-1][0] == 403, replies[-1]
        assert counter.count == 0

    # The page's own origin, on each name it is reached by: both sockets open and the Twists arrive (each on a
    # topic of its own, so that every one is seen to arrive).
    own = [
        (host, protocol, port, f"/cmd_vel_{i}")
        for i, (host, (protocol, port)) in enumerate(
            (h, p) for h in ("127.0.0.1", "localhost") for p in (("rosbridge", ros), ("foxglove", fox))
        )
    ]
    with contextlib.ExitStack() as stack:
        counters = [
            stack.enter_context(CmdVelCounter(daemon.uri, t, name=f"counter{i}")) for i, (*_, t) in enumerate(own)
        ]
        replies = browse(
            [attack(f"http://{h}:{fox}/", [(f"ws://{h}:{port}/", protocol, 30, t)]) for h, protocol, port, t in own]
        )
        for (host, protocol, _, topic), (status, results), counter in zip(own, replies, counters, strict=True):
            assert status == 200 and results[0]["open"], (host, protocol, results)
            assert counter.wait_for(1, 10), (host, protocol, topic, counter.count)


def test_clients_without_an_origin_still_connect(daemon: WebDaemon) -> None:
    """node, Python and Foxglove desktop send no Origin: they connect to both ports and publish."""

    async def main() -> None:
        async with aiohttp.ClientSession() as http:
            ws = await http.ws_connect(daemon.rosbridge_url)
            await ws.send_str(json.dumps({"op": "advertise", "topic": TOPIC, "type": "geometry_msgs/Twist"}))
            for _ in range(40):
                await ws.send_str(json.dumps({"op": "publish", "topic": TOPIC, "msg": {"linear": {"x": 1}}}))
                await asyncio.sleep(0.05)
                if counter.count:
                    break
            await ws.close()
            ws = await http.ws_connect(daemon.foxglove_url, protocols=["foxglove.websocket.v1"])
            assert json.loads((await ws.receive(timeout=10)).data)["op"] == "serverInfo"
            await ws.close()

    # a topic of this test's own: rosbridge keeps a publisher 10 s after its client and re-sends its first second
    # to late subscribers, which would reach the next test's /cmd_vel subscriber
    TOPIC = "/cmd_vel_plain"
    with CmdVelCounter(daemon.uri, TOPIC) as counter:
        asyncio.run(main())
        assert counter.count > 0


#: From the page it runs in, POSTs XML-RPC calls the way any page may: ``fetch`` in ``no-cors`` mode with a
#: ``text/plain`` body (no preflight; the page cannot read the answer, but the call is made). Each item is
#: ``{url, body}``; the result says whether the fetch went out without a network error.
CSRF = """async (calls) => {
  const results = [];
  for (const {url, body} of calls) {
    try {
      await fetch(url, { method: "POST", mode: "no-cors", headers: { "Content-Type": "text/plain" }, body });
      results.push("sent");
    } catch (e) { results.push(String(e)); }
  }
  return results;
}"""


class _AttackerHost:
    """The attacker's own machine: a master of its own and a node publishing Twists on /cmd_vel at 20 Hz. Its
    slave API is what a hijacked subscriber on the robot would call (``requestTopic``) and take data from."""

    def __init__(self) -> None:
        self.node_uri = ""
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self._thread.start()
        assert self._ready.wait(20) and self.node_uri

    async def _main(self) -> None:
        import mrosd
        from mrosd.master.server import Master
        from mrosd.msg import get_message_class

        twist = get_message_class("geometry_msgs/Twist")
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        async with (
            Master("127.0.0.1", 0) as master,
            mrosd.Node("attacker", master_uri=master.uri, argv=[], host="127.0.0.1") as node,
        ):
            pub = await node.advertise("/cmd_vel", twist)
            self.node_uri = node.uri
            self._ready.set()
            while not self._stop.is_set():
                pub.publish_nowait(twist(linear=get_message_class("geometry_msgs/Vector3")(x=2.0)))
                try:
                    await asyncio.wait_for(self._stop.wait(), 0.05)
                except TimeoutError:
                    pass

    def close(self) -> None:
        if self._loop is not None and self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)


def _call(method: str, *params: Any) -> str:
    return xmlrpc.client.dumps(params, method)


def test_a_foreign_page_cannot_call_the_master_or_a_nodes_slave_api(daemon: WebDaemon, foreign_site: int) -> None:
    """Any page may POST to any port with ``fetch`` (no-cors, text/plain): XML-RPC needs no preflight, so a page
    could set parameters, register a publisher on /cmd_vel whose node is on the attacker's machine (every
    subscriber then connects to it and takes its Twists), or tell a node to shut down. Both the master and a
    node's slave API refuse a request that carries ``Origin`` (a browser's); ROS clients send none."""
    attacker = _AttackerHost()
    try:
        with CmdVelCounter(daemon.uri) as counter, xmlrpc.client.ServerProxy(daemon.uri) as master:
            sub_api = master.lookupNode("/probe", "/cmd_vel_counter")[2]
            calls = [
                (daemon.uri, _call("setParam", "/page", "/pwned", 1)),
                (daemon.uri, _call("registerPublisher", "/evil", "/cmd_vel", "geometry_msgs/Twist", attacker.node_uri)),
                (sub_api, _call("publisherUpdate", "/master", "/cmd_vel", [attacker.node_uri])),
            ]
            jobs: list[tuple[str, str, Any]] = [
                (page, CSRF, [{"url": url, "body": body} for url, body in calls])
                for page in (f"http://attacker.test:{foreign_site}/", f"http://127.0.0.1:{foreign_site}/")
            ]
            # DNS rebinding: the attacker's name now resolves to the robot, so its page is same-origin with the
            # master's port and could read the answers too.
            rebound = [{"url": "/", "body": _call("setParam", "/p", "/pwned2", 1)}]
            jobs.append((f"http://attacker.test:{daemon.port}/", CSRF, rebound))
            for (_, _, arg), (_, results) in zip(jobs, browse(jobs), strict=True):
                assert results == ["sent"] * len(arg), results
            _, _, names = master.getParamNames("/probe")
            assert "/pwned" not in names and "/pwned2" not in names, names
            state = master.getSystemState("/probe")[2]
            assert ["/cmd_vel", ["/cmd_vel_counter"]] in state[1]
            assert not [t for t, nodes in state[0] if t == "/cmd_vel" and "/evil" in nodes], state[0]
            # Had either call gone through, the subscriber would be taking the attacker's Twists by now (20 Hz).
            assert not counter.wait_for(1, 2.0), counter.count
            # A ROS client (no Origin) still sets parameters and the node still answers.
            assert master.setParam("/probe", "/fine", 1)[0] == 1
            with xmlrpc.client.ServerProxy(sub_api) as node:
                assert node.getPid("/probe")[0] == 1
    finally:
        attacker.close()
