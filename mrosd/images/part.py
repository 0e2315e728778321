"""The daemon's ``[images]`` part: ``T/compressed`` in the ROS graph for every sensor_msgs/Image topic ``T``
matching a configured glob, as image_transport's ``compressed`` plugin would publish it beside ``T``.

Lazy, as image_transport's publishers are: ``T/compressed`` is advertised as soon as ``T`` appears, but ``T``
is subscribed only while ``T/compressed`` has a subscriber (the publisher's own connection count), and dropped
again when the last one leaves. Each topic has one encoder task: the subscription's callback only keeps the
newest image (a newer one replaces one not yet encoded, counted in ``dropped``); the task encodes it in the
part's worker threads, once for all subscribers, and publishes it with the raw image's header.

An image a peer sent that cannot be encoded (bad sizes, an unsupported encoding) is one rate-limited log
line; the topic keeps going.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from mrosd import backports
from mrosd.errors import MrosError
from mrosd.fleet.keys import glob_match
from mrosd.images.compress import encode_image
from mrosd.images.encoding import EncodeSettings, ImageError, RawImage
from mrosd.lograte import RateLimitedLog
from mrosd.master.client import watch_graph
from mrosd.tcpros.node import Node

__all__ = ["IMAGE_TYPE", "NODE_NAME", "CompressedImages"]

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

NODE_NAME = "/mrosd_images"
IMAGE_TYPE = "sensor_msgs/Image"
SUFFIX = "/compressed"
#: How often an active topic checks that ``T/compressed`` still has subscribers while no image arrives.
IDLE_CHECK = 0.25
#: How long an idle topic waits for its first subscriber before looking again (the loop also ends on close).
WAIT_CHECK = 5.0
#: Seconds before a subscription the master refused is tried again.
RETRY_DELAY = 2.0
#: Encoder threads shared by all topics: JPEG encoders release the GIL, so two use both cores of a small
#: robot computer without starving the event loop's own thread.
WORKERS = 2


@dataclass(slots=True)
class TopicStats:
    """Per topic: images received, encoded, dropped (replaced before encoding), refused (bad images)."""

    received: int = 0
    encoded: int = 0
    dropped: int = 0
    refused: int = 0
    subscribed: bool = False
    last_error: str = ""


@dataclass(slots=True)
class _Topic:
    raw: str
    publisher: Any
    task: asyncio.Task[None] | None = None
    latest: Any = None
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    stats: TopicStats = field(default_factory=TopicStats)


class CompressedImages:
    """Publishes ``T/compressed`` for the Image topics matching ``patterns``; ``start()``/``aclose()``.

    Args:
        master_uri: the master to register with.
        patterns: global-name globs (``*`` within a segment, ``**`` across), as in ``[fleet]``.
        settings: JPEG quality, maximum width, PNG level, for every topic.
        node_kwargs: passed to the part's ``Node`` (``admission`` caps from the daemon's budget).
    """

    def __init__(
        self,
        master_uri: str,
        patterns: list[str],
        settings: EncodeSettings | None = None,
        **node_kwargs: Any,
    ) -> None:
        self.master_uri = master_uri
        self.patterns = list(patterns)
        self.settings = settings or EncodeSettings()
        self.topics: dict[str, _Topic] = {}
        self._node_kwargs = node_kwargs
        self._node: Node | None = None
        self._graph_task: asyncio.Task[None] | None = None
        self._executor: ThreadPoolExecutor | None = None
        from mrosd.msg import get_message_class

        self._image_cls = get_message_class(IMAGE_TYPE)
        self._compressed_cls = get_message_class("sensor_msgs/CompressedImage")

    def wanted(self, topic: str, msg_type: str) -> bool:
        """Whether ``topic`` gets a ``/compressed`` twin: an Image topic matching a pattern."""
        return msg_type == IMAGE_TYPE and any(glob_match(p, topic) for p in self.patterns)

    async def start(self) -> None:
        """Register the node and start following the graph.

        Raises:
            MrosError: the master does not answer.
        """
        node = Node(NODE_NAME, master_uri=self.master_uri, argv=[], rosout=False, **self._node_kwargs)
        await node.start()
        self._node = node
        self._executor = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="mrosd-images")
        self._graph_task = asyncio.create_task(self._follow_graph(), name="images-graph")
        from mrosd.images.jpeg import available_encoders

        # loads numpy and the libraries: off the loop, and the first image does not pay for it
        jpeg = await asyncio.get_running_loop().run_in_executor(self._executor, available_encoders)
        if not jpeg:
            log.warning(
                "images: no JPEG encoder installed: 8-bit images will not be compressed; "
                "pip install 'mrosd[images]' (16-bit depth images are, as PNG)"
            )
        log.info(
            "images: T/compressed on demand for %s (JPEG: %s)", ", ".join(self.patterns), jpeg[0] if jpeg else "none"
        )

    async def aclose(self) -> None:
        """Stop every topic, close the node and the worker threads."""
        tasks = [t.task for t in self.topics.values() if t.task is not None]
        if self._graph_task is not None:
            tasks.append(self._graph_task)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self.topics.clear()
        if self._node is not None:
            await self._node.aclose()
            self._node = None
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    def status(self) -> dict[str, TopicStats]:
        """Per raw topic: what was received, encoded, dropped and refused."""
        return {name: topic.stats for name, topic in self.topics.items()}

    async def _follow_graph(self) -> None:
        assert self._node is not None
        async for graph in watch_graph(self._node.master, poll_interval=0.5):
            present = {name for name, ty in graph.topics.items() if self.wanted(name, ty)}
            for name in present - self.topics.keys():
                try:
                    await self._add(name)
                except MrosError as exc:
                    _ratelog.warning(f"advertise {name}", "images: cannot publish %s%s: %s", name, SUFFIX, exc)
            for name in self.topics.keys() - present:
                await self._remove(name)

    async def _add(self, raw: str) -> None:
        assert self._node is not None
        pub = await self._node.advertise(raw + SUFFIX, self._compressed_cls, queue_size=2)
        topic = _Topic(raw, pub)
        self.topics[raw] = topic
        topic.task = asyncio.create_task(self._serve(topic), name=f"images{raw}")
        log.info("images: %s%s advertised", raw, SUFFIX)

    async def _remove(self, raw: str) -> None:
        topic = self.topics.pop(raw)
        if topic.task is not None:
            topic.task.cancel()
            await asyncio.gather(topic.task, return_exceptions=True)
        with contextlib.suppress(MrosError):
            await topic.publisher.aclose()

    async def _serve(self, topic: _Topic) -> None:
        """Subscribe to the raw topic while ``/compressed`` has subscribers; encode the newest image."""
        assert self._node is not None
        pub = topic.publisher
        while True:
            try:
                await pub.wait_for_subscribers(1, timeout=WAIT_CHECK)
            except TimeoutError:
                continue

            def keep(msg: Any, topic: _Topic = topic) -> None:
                topic.stats.received += 1
                if topic.latest is not None:
                    topic.stats.dropped += 1
                topic.latest = msg
                topic.ready.set()

            try:
                sub = await self._node.subscribe(topic.raw, self._image_cls, keep, queue_size=1)
            except MrosError as exc:  # the master refused or did not answer: try again later
                _ratelog.warning(f"subscribe {topic.raw}", "images: cannot subscribe to %s: %s", topic.raw, exc)
                await asyncio.sleep(RETRY_DELAY)
                continue
            topic.stats.subscribed = True
            try:
                while pub.get_num_connections() > 0:
                    try:
                        async with backports.timeout(IDLE_CHECK):
                            await topic.ready.wait()
                    except TimeoutError:
                        continue
                    topic.ready.clear()
                    msg, topic.latest = topic.latest, None
                    if msg is not None:
                        await self._encode_and_publish(topic, msg)
            finally:
                topic.stats.subscribed = False
                topic.latest = None
                await sub.aclose()

    async def _encode_and_publish(self, topic: _Topic, msg: Any) -> None:
        loop = asyncio.get_running_loop()
        try:
            frame = await loop.run_in_executor(self._executor, encode_image, RawImage.of(msg), self.settings)
        except ImageError as exc:
            topic.stats.refused += 1
            topic.stats.last_error = str(exc)
            _ratelog.warning(f"encode {topic.raw}", "images: %s: %s", topic.raw, exc)
            return
        out = self._compressed_cls(header=msg.header, format=frame.format, data=frame.data)
        try:
            topic.publisher.publish_nowait(out)
        except MrosError as exc:  # the publisher closed under us (topic removed)
            log.debug("images: %s%s: %s", topic.raw, SUFFIX, exc)
            return
        topic.stats.encoded += 1
