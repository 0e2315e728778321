"""``T/compressed`` for browser clients: for every sensor_msgs/Image topic ``T`` the hub offers, a
sensor_msgs/CompressedImage topic ``T/compressed`` as image_transport's ``compressed`` plugin writes it
(``mrosd.images``), unless the ROS graph already has one (a real image_transport publisher, or the daemon's
``[images]`` part): then that real topic is what clients get, and nothing is encoded here.

A virtual topic is one more upstream of the hub's shared subscriptions (``mrosd.web.shared``): its first sink
opens a ``CompressedSource``, which holds ``T``'s raw shared subscription with a sink of its own and hands the
encoded bodies to the same fan-out as any topic's TCPROS bodies, so every protocol delivers them as it delivers
any topic. One source per topic, whatever the number of clients: encoded once, with the topic's settings.

- newest only: a raw frame that arrives while one is being encoded replaces the one waiting (``dropped``);
- a big frame (``PAUSE_BYTES``) stops the hub reading ``T`` until it is encoded, when no client reads ``T``
  itself: the next one waits in the publisher's queue, not in the daemon (a frame received only to be
  replaced cost a frame of memory: 100 MB for a 100 MB camera); the worker drops the frame as it is done;
- off the loop: the conversion runs in ``WORKERS`` threads (libjpeg-turbo releases the GIL), in batches of
  the frames of many topics (one hand-over per batch, not per frame: the loop's cost with hundreds of
  cameras); the sources wait in one ordered set, oldest first;
- ``max_rate``: at most that many encodes a second (the rest dropped as above), on one timer for all topics;
- the last sink to leave closes the source, and the source's sink on ``T`` (the raw subscription closes
  with its last sink);
- a frame that cannot be encoded (sizes that disagree with its bytes, an unsupported encoding) is counted
  in ``refused`` and logged once per ``LOG_PERIOD`` per topic; the next frame is encoded as usual.

Settings (quality, maximum width, maximum rate) come from the ``[[web.images]]`` rules (first match) and can
be changed per topic by a client (``set_settings``): one setting per topic, shared by every client, the last
writer wins, so clients can never make more than one encoder per topic.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import heapq
import logging
import time
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, cast

from mrosd.errors import MrosError
from mrosd.fleet.keys import glob_match
from mrosd.images.compress import encode_image
from mrosd.images.encoding import MAX_SIDE, EncodeSettings
from mrosd.images.wire import read_image
from mrosd.lograte import RateLimitedLog
from mrosd.tcpros import Node
from mrosd.tcpros.subscriber import Subscriber
from mrosd.web.shared import PAUSE_BYTES, SharedSubscriptions

__all__ = [
    "COMPRESSED_TYPE",
    "IMAGE_TYPE",
    "SUFFIX",
    "CompressedSource",
    "CompressedTopics",
    "ImageRule",
    "ImageSettings",
    "VirtualSubscriptions",
    "compress_image_body",
    "rules_from_config",
]

log = logging.getLogger(__name__)
#: seconds between two log lines about one topic's refused frames
LOG_PERIOD = 10.0
_ratelog = RateLimitedLog(log, period=LOG_PERIOD, burst=1)

IMAGE_TYPE = "sensor_msgs/Image"
COMPRESSED_TYPE = "sensor_msgs/CompressedImage"
SUFFIX = "/compressed"
#: Encoder threads shared by every topic (as the ``[images]`` part: two use both cores of a small robot).
WORKERS = 2
#: A worker's batch: frames of several topics while it holds less than ``BATCH_BYTES`` of them (a big frame
#: goes alone), at most ``BATCH_FRAMES``. One hand-over to a thread and back per batch, not per frame: 500
#: small cameras at 10 Hz were 5,000 executor round trips a second on the loop, each a future, a wake-up of
#: the loop and a task step.
BATCH_FRAMES = 64
BATCH_BYTES = 1024 * 1024
#: Highest ``max_rate`` a client may ask (a camera faster than this is rare; 0 means no limit).
MAX_RATE = 240.0
#: Narrowest ``max_width`` (0: keep the camera's width); below it a picture shows nothing useful.
MIN_WIDTH = 16


@dataclass(frozen=True, slots=True)
class ImageSettings:
    """One topic's encoder settings: JPEG ``quality`` 1..100, ``max_width`` (0: keep; else 16..16384, scaled
    down by a whole factor), ``max_rate`` encodes per second (0: every frame, at most 240).

    Raises:
        ValueError: a value outside its range (the message names it).
    """

    quality: int = 80
    max_width: int = 0
    max_rate: float = 0.0

    def __post_init__(self) -> None:
        if not 1 <= self.quality <= 100:
            raise ValueError(f"quality must be 1..100, got {self.quality}")
        if self.max_width != 0 and not MIN_WIDTH <= self.max_width <= MAX_SIDE:
            raise ValueError(f"max_width must be 0 or {MIN_WIDTH}..{MAX_SIDE}, got {self.max_width}")
        if not 0 <= self.max_rate <= MAX_RATE:
            raise ValueError(f"max_rate must be 0..{MAX_RATE:g}, got {self.max_rate}")

    def encode_settings(self) -> EncodeSettings:
        return EncodeSettings(quality=self.quality, max_width=self.max_width)

    def as_dict(self) -> dict[str, Any]:
        return {"quality": self.quality, "maxWidth": self.max_width, "maxRate": self.max_rate}


@dataclass(frozen=True, slots=True)
class ImageRule:
    """``[[web.images]]``: the settings of the raw Image topics matching one of ``topics`` (globs)."""

    topics: tuple[str, ...]
    settings: ImageSettings


def rules_from_config(tables: Iterable[Any]) -> list[ImageRule]:
    """``[[web.images]]`` tables (``mrosd.config.WebImagesConfig``, already checked) as rules."""
    return [
        ImageRule(tuple(t.topics), ImageSettings(quality=t.quality, max_width=t.max_width, max_rate=t.max_rate))
        for t in tables
    ]


@dataclass(slots=True)
class SourceStats:
    """Per virtual topic, since the daemon started: raw frames received, encoded, dropped (replaced before
    encoding), refused (could not be encoded), the time spent encoding and the bytes it made."""

    received: int = 0
    encoded: int = 0
    dropped: int = 0
    refused: int = 0
    encode_ns: int = 0
    bytes_out: int = 0

    def as_dict(self) -> dict[str, Any]:
        calls = self.encoded + self.refused
        return {
            "received": self.received,
            "encoded": self.encoded,
            "dropped": self.dropped,
            "refused": self.refused,
            "encodeMs": round(self.encode_ns / calls / 1e6, 2) if calls else None,
            "bytesPerFrame": self.bytes_out // self.encoded if self.encoded else None,
        }


def compress_image_body(body: bytes | bytearray | memoryview, settings: EncodeSettings) -> bytes:
    """A serialized sensor_msgs/Image -> the serialized CompressedImage the plugin would publish (same header).
    Pure; runs in a worker thread. The pixels are read where TCPROS received them (``read_image``: no copy
    of a frame that may be 100 MB).

    Raises:
        MrosError: the body is not an Image (``MsgError``), or the image cannot be encoded (``ImageError``).
    """
    view = read_image(body)
    frame = encode_image(view.image, settings)
    fmt = frame.format.encode()
    return b"".join(
        (
            view.header,
            len(fmt).to_bytes(4, "little"),
            fmt,
            len(frame.data).to_bytes(4, "little"),
            frame.data,
        )
    )


def _encode_batch(jobs: list[tuple[list[bytes | bytearray], EncodeSettings]]) -> list[tuple[bytes | str, int]]:
    """In a worker thread: each job's body encoded, taken out of its box as it starts (the worker holds no
    frame once it is done with it: TCPROS then receives the next frame into that buffer). Per job: the
    CompressedImage, or the refusal's message (not the exception: its traceback would keep the frame), and
    the nanoseconds it took."""
    results: list[tuple[bytes | str, int]] = []
    for box, settings in jobs:
        started = time.perf_counter_ns()
        try:
            out: bytes | str = compress_image_body(box.pop(), settings)
        except (MrosError, ValueError, RuntimeError, OSError) as exc:  # an encoder's own refusal too
            out = str(exc) or type(exc).__name__
        results.append((out, time.perf_counter_ns() - started))
    return results


class _Body:
    """What the shared fan-out reads of a received message: its ``data``."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data


class _RawSink:
    """The source's sink on ``T``: keeps only the newest raw body (holds nothing the hub would pause for)."""

    def __init__(self, source: CompressedSource) -> None:
        self.source = source

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        source = self.source
        source.stats.received += 1
        if source.latest is not None:
            source.stats.dropped += 1
        source.latest = body
        if not source.busy and not source.scheduled:
            source.owner.want(source)
        if len(body) >= PAUSE_BYTES and not source.held:
            # a big frame: T is not read until the encoder is done with it, so no second one is received
            # meanwhile only to wait (and be replaced); the publisher's queue keeps the newest instead. Paused
            # here, as it arrives: by the time the encoder task runs, the next frame's first bytes would have
            # made TCPROS allocate its whole buffer.
            source.held = source.owner.hold_raw(source.raw, self)

    def backlog(self, topic: str) -> int:
        """The frame waiting while another is encoded: behind by its size, so that the hub stops reading ``T``
        once it is big (``PAUSE_BYTES``) and no other sink of ``T`` still reads. The next frame then waits in
        the publisher's queue and the kernel's buffers instead of being received only to replace this one."""
        source = self.source
        latest = source.latest
        return len(latest) if source.busy and latest is not None else 0

    def queued(self) -> int:
        return 0

    def shed_oldest(self) -> None:
        pass


@dataclass(slots=True, eq=False)
class CompressedSource:
    """The upstream of one virtual ``T/compressed``: what ``SharedSubscriptions`` holds as its subscriber.
    Its task only holds ``T``'s shared subscription; its frames are encoded by ``CompressedTopics``."""

    name: str
    raw: str
    owner: CompressedTopics
    emit: Callable[[Any], None]
    stats: SourceStats
    #: the shared fan-out pauses a subscriber's links; a source has none
    links: dict[Any, Any] = field(default_factory=dict)
    latest: bytes | bytearray | None = None
    #: a frame of it is in a worker's batch (a frame that arrives meanwhile waits in ``latest``)
    busy: bool = False
    #: waiting for its ``max_rate`` (on the owner's one timer)
    scheduled: bool = False
    #: when its ``max_rate`` lets it encode again (monotonic ns)
    next_ns: int = 0
    #: the hub stopped reading ``T`` for this source (a big frame waits or is being encoded)
    held: bool = False
    task: asyncio.Task[None] | None = None

    @property
    def live(self) -> bool:
        return self.owner.sources.get(self.name) is self

    async def aclose(self) -> None:
        """Stop encoding (the task leaves ``T``'s shared subscription on its way out, after the caller's lock)."""
        if self.task is not None:
            self.task.cancel()
        if self.live:  # not a newer source of the same name
            del self.owner.sources[self.name]
        self.owner.forget(self)

    def release(self) -> None:
        """Read ``T`` again if it was stopped for this source (a frame it held, or one that waited)."""
        if self.held or self.latest is not None:
            self.held = False
            self.owner.resume_raw(self.raw)

    async def run(self) -> None:
        owner = self.owner
        sink = _RawSink(self)
        try:
            await owner.add_raw_sink(self.raw, sink)
            await asyncio.get_running_loop().create_future()  # until closed: the frames go to the owner
        except MrosError as exc:  # the raw topic could not be subscribed
            _ratelog.warning(self.name, "web: %s cannot be made: %s", self.name, exc)
        finally:
            self.latest = None
            owner.forget(self)
            with contextlib.suppress(MrosError):
                await asyncio.shield(owner.remove_raw_sink(self.raw, sink))


class CompressedTopics:
    """The hub's virtual ``T/compressed`` topics: which are offered, their settings, their sources.

    ``add_raw_sink``/``remove_raw_sink`` are the hub's shared subscription calls (``check=False``: the hub
    only offers ``T/compressed`` when its policy allows both names).
    """

    def __init__(
        self,
        add_raw_sink: Callable[[str, Any], Any],
        remove_raw_sink: Callable[[str, Any], Any],
        rules: Iterable[ImageRule] = (),
        hold_raw: Callable[[str, Any], bool] = lambda topic, sink: False,
        resume_raw: Callable[[str], None] = lambda topic: None,
    ) -> None:
        self.add_raw_sink = add_raw_sink
        self.remove_raw_sink = remove_raw_sink
        #: the hub's: stop reading ``T`` while its only sink, an encoder, works on a big frame (True: paused)
        self.hold_raw = hold_raw
        #: the hub's ``resume``: read ``T`` again
        self.resume_raw = resume_raw
        self.rules: list[ImageRule] = list(rules)
        #: virtual topic names offered now -> their raw topic
        self.virtual: dict[str, str] = {}
        self.sources: dict[str, CompressedSource] = {}
        #: per virtual topic, since it was first offered (kept while it is offered)
        self.stats: dict[str, SourceStats] = {}
        #: settings set by clients, per offered virtual topic (at most one entry per offered topic)
        self.overrides: dict[str, ImageSettings] = {}
        self._executor: ThreadPoolExecutor | None = None
        #: sources with a frame to encode, not in a batch, oldest first (a dict as an ordered set)
        self._ready: dict[CompressedSource, None] = {}
        #: batches in the workers now (at most ``WORKERS``)
        self._batches = 0
        #: sources waiting for their ``max_rate``: (due, order, source), on one timer for all of them
        self._due: list[tuple[int, int, CompressedSource]] = []
        self._due_order = 0
        self._timer: asyncio.TimerHandle | None = None

    def executor(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="mrosd-web-images")
        return self._executor

    # --- encoding -----------------------------------------------------------------------------------------

    def want(self, source: CompressedSource) -> None:
        """``source`` has a frame and none in a batch: into the next batch, or onto the timer of its rate."""
        if source.next_ns > time.monotonic_ns():
            source.scheduled = True  # the waiting frame is replaced by newer ones until then
            earliest = self._timer is None or not self._due or source.next_ns < self._due[0][0]
            self._due_order += 1
            heapq.heappush(self._due, (source.next_ns, self._due_order, source))
            if earliest:
                self._arm()
            return
        self._ready[source] = None
        if self._batches < WORKERS:
            self._start_batches()

    def forget(self, source: CompressedSource) -> None:
        """``source`` closed: out of the next batch (a batch under way still ends, its output dropped)."""
        self._ready.pop(source, None)

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = None
        if self._due:
            loop = asyncio.get_running_loop()
            delay = max(0.0, (self._due[0][0] - time.monotonic_ns()) / 1e9)
            self._timer = loop.call_later(delay, self._due_now)

    def _due_now(self) -> None:
        self._timer = None
        now = time.monotonic_ns()
        while self._due and self._due[0][0] <= now:
            _, _, source = heapq.heappop(self._due)
            source.scheduled = False
            if source.live and source.latest is not None and not source.busy:
                self._ready[source] = None
        self._arm()
        self._start_batches()

    def _start_batches(self) -> None:
        """Hand the ready sources' frames to the workers, a batch per free worker."""
        loop = asyncio.get_running_loop()
        while self._ready and self._batches < WORKERS:
            sources: list[CompressedSource] = []
            jobs: list[tuple[list[bytes | bytearray], EncodeSettings]] = []
            size = 0
            now = time.monotonic_ns()
            while self._ready and len(jobs) < BATCH_FRAMES and size < BATCH_BYTES:
                source = next(iter(self._ready))
                del self._ready[source]
                body, source.latest = source.latest, None
                if body is None or not source.live:
                    continue
                settings = self.settings_for(source.name)
                if settings.max_rate > 0:
                    source.next_ns = now + int(1e9 / settings.max_rate)
                source.busy = True
                sources.append(source)
                jobs.append(([body], settings.encode_settings()))
                size += len(body)
                del body
            if not jobs:
                return
            self._batches += 1
            done = loop.run_in_executor(self.executor(), _encode_batch, jobs)
            done.add_done_callback(functools.partial(self._batch_done, sources))

    def _batch_done(self, sources: list[CompressedSource], done: asyncio.Future[list[tuple[bytes | str, int]]]) -> None:
        self._batches -= 1
        results: list[tuple[bytes | str, int]] = []
        if not done.cancelled():
            error = done.exception()
            if error is not None:  # a bug, not a peer's doing: said loudly, once per batch
                log.error("web: an encoder batch failed", exc_info=error)
            else:
                results = done.result()
        for i, source in enumerate(sources):
            source.busy = False
            # the raw frame was dropped by the worker: TCPROS may read the next one into its buffer
            source.release()
            if i < len(results) and source.live:
                out, took = results[i]
                stats = source.stats
                stats.encode_ns += took
                if isinstance(out, str):
                    stats.refused += 1
                    _ratelog.warning(
                        source.name, "web: %s: a frame of %s was not encoded: %s", source.name, source.raw, out
                    )
                else:
                    stats.encoded += 1
                    stats.bytes_out += len(out)
                    source.emit(_Body(out))
            if source.latest is not None and source.live and not source.scheduled:
                self.want(source)
        if self._executor is not None:
            self._start_batches()

    # --- which topics are virtual ----------------------------------------------------------------------

    @staticmethod
    def affected(names: Iterable[str]) -> set[str]:
        """The virtual names a change of ``names`` in the graph may add or remove."""
        out: set[str] = set()
        for name in names:
            out.add(name + SUFFIX)
            if name.endswith(SUFFIX):
                out.add(name)
        return out

    def update(
        self, name: str, topics: Mapping[str, str], publishers: Mapping[str, Any], allowed: Callable[[str], bool]
    ) -> bool | None:
        """Bring virtual ``name`` in line with the graph: True when it became virtual, False when it stopped
        being virtual, None when nothing changed. Virtual while ``T`` is an Image topic, both names are
        allowed, and no one publishes ``name`` in the graph."""
        raw = name.removesuffix(SUFFIX)
        want = (
            topics.get(raw) == IMAGE_TYPE
            and not publishers.get(name)
            and raw != name
            and allowed(raw)
            and allowed(name)
        )
        if want == (name in self.virtual):
            return None
        if want:
            self.virtual[name] = raw
            self.stats.setdefault(name, SourceStats())
        else:
            del self.virtual[name]
            self.overrides.pop(name, None)
            self.stats.pop(name, None)
        return want

    # --- settings -------------------------------------------------------------------------------------

    def settings_for(self, name: str) -> ImageSettings:
        override = self.overrides.get(name)
        if override is not None:
            return override
        raw = name.removesuffix(SUFFIX)
        for rule in self.rules:
            if any(glob_match(p, raw) for p in rule.topics):
                return rule.settings
        return ImageSettings()

    def set_settings(self, name: str, settings: ImageSettings) -> None:
        """A client's settings for ``name``, shared by every client (the last writer wins).

        Raises:
            MrosError: ``name`` is not a compressed topic made here.
        """
        if name not in self.virtual:
            raise MrosError(f"{name} is not a compressed topic made by mrosd (a real one, or not offered)")
        self.overrides[name] = settings

    # --- sources ------------------------------------------------------------------------------------------

    def open(self, name: str, emit: Callable[[Any], None]) -> CompressedSource | None:
        """The source of virtual ``name`` (None: not virtual, subscribe to the real topic)."""
        raw = self.virtual.get(name)
        if raw is None:
            return None
        source = CompressedSource(name, raw, self, emit, self.stats.setdefault(name, SourceStats()))
        old = self.sources.pop(name, None)
        if old is not None and old.task is not None:
            old.task.cancel()
        self.sources[name] = source
        source.task = asyncio.get_running_loop().create_task(source.run(), name=f"web compressed {name}")
        return source

    def status(self) -> dict[str, dict[str, Any]]:
        """Per offered virtual topic: its counters, whether it is encoding now, its settings."""
        return {
            name: {
                **self.stats.get(name, SourceStats()).as_dict(),
                "active": name in self.sources,
                **self.settings_for(name).as_dict(),
            }
            for name in sorted(self.virtual)
        }

    async def aclose(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._due.clear()
        self._ready.clear()
        tasks = [s.task for s in self.sources.values() if s.task is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self.sources.clear()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None


class VirtualSubscriptions(SharedSubscriptions):
    """The hub's shared subscriptions, where a virtual ``T/compressed`` is upstreamed by its encoder instead
    of a TCPROS subscription (the fan-out, counters and client queues are the same for both)."""

    def __init__(self, node: Node, compressed: CompressedTopics, **kwargs: Any) -> None:
        super().__init__(node, **kwargs)
        self.compressed = compressed

    async def subscribe(self, topic: str) -> Subscriber:
        source = self.compressed.open(topic, self._raw_callback(topic))
        if source is not None:
            # duck-typed as the fan-out uses a subscriber: ``links`` (none to pause) and ``aclose``
            return cast("Subscriber", source)
        return await super().subscribe(topic)

    async def reconcile(self, topic: str) -> None:
        """``topic`` became virtual or stopped being so while sinks hold it (a rosbridge subscription is by
        name and outlives the channel): give its sinks the right upstream, the real topic's or an encoder."""
        async with self._lock:
            entry = self.entries.get(topic)
            if entry is None:
                return
            made = isinstance(entry.subscriber, CompressedSource)
            if made == (topic in self.compressed.virtual):
                return
            await entry.subscriber.aclose()
            entry.subscriber = await self.subscribe(topic)
            entry.paused = False
