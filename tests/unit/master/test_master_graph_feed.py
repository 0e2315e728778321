"""``GraphFeed``: the names each registry change touches, read back as deltas, rebuild the same graph as a
fresh snapshot, whatever the sequence (registrations, replaced nodes, swept nodes, moved services)."""

from __future__ import annotations

import random

from mrosd.master.client import GraphDelta, GraphSnapshot, graph_delta
from mrosd.master.registry import Registry
from mrosd.master.server import GraphFeed
from mrosd.web.graphwatch import LiveGraph


def frozen(graph: LiveGraph) -> GraphSnapshot:
    return GraphSnapshot(frozenset(graph.nodes), dict(graph.topics), dict(graph.services), dict(graph.publishers))


def random_step(reg: Registry, rng: random.Random) -> None:
    node = f"/n{rng.randrange(6)}"
    api = f"http://h:{rng.randrange(3)}/"  # a node seen at another URI is replaced
    topic = f"/t{rng.randrange(8)}"
    service = f"/s{rng.randrange(5)}"
    kind = rng.randrange(9)
    if kind == 0:
        reg.register_publisher(node, topic, rng.choice(["a/A", "b/B", "*"]), api)
    elif kind == 1:
        reg.unregister_publisher(node, topic, api)
    elif kind == 2:
        reg.register_subscriber(node, topic, rng.choice(["a/A", "*"]), api)
    elif kind == 3:
        reg.unregister_subscriber(node, topic, api)
    elif kind == 4:
        reg.register_service(node, service, f"rosrpc://h:{rng.randrange(3)}", api)
    elif kind == 5:
        entry = reg.services.get(service)
        if entry is not None:
            reg.unregister_service(entry.node, service, entry.service_api)
    elif kind == 6:
        reg.subscribe_param(node, "/p/", api)
    elif kind == 7:
        reg.unsubscribe_param(node, "/p/", api)
    else:
        reg.remove_node(node)  # the graph sweep


async def test_deltas_rebuild_the_same_graph_as_a_snapshot() -> None:
    rng = random.Random(31)
    reg = Registry()
    feed = GraphFeed(reg)
    live = LiveGraph()
    live.apply(graph_delta(GraphSnapshot(), feed.snapshot()))
    for _ in range(400):
        for _ in range(rng.randrange(1, 4)):  # several changes coalesce into one delta
            random_step(reg, rng)
        if not (feed.topics or feed.services or feed.nodes):
            continue
        delta = await feed.next_delta()
        live.apply(delta)
        assert frozen(live) == feed.snapshot()
    feed.close()
    assert reg.journals == []


async def test_a_delta_holds_only_the_names_that_changed() -> None:
    reg = Registry()
    for i in range(1000):
        reg.register_publisher("/big", f"/t{i}", "a/A", "http://h:1/")
    feed = GraphFeed(reg)
    reg.register_publisher("/cam", "/image", "sensor_msgs/Image", "http://h:2/")
    delta = await feed.next_delta()
    assert delta == GraphDelta(
        topics={"/image": "sensor_msgs/Image"}, publishers={"/image": ("/cam",)}, nodes={"/cam": True}
    )
    feed.close()
