"""tf2_web_republisher in the daemon: its ``/republish_tfs`` service and its action, answered from one Buffer.

roslibpy's ``TFClient`` calls ``/republish_tfs`` (``tf2_web_republisher/RepublishTFs``) and subscribes to the
``tf2_web_republisher/TFArray`` topic it names; roslibjs's ``TFClient`` sends a goal to the
``/tf2_web_republisher`` action (``tf2_web_republisher/TFSubscription``) and reads the feedback. Both work with
no tf2_web_republisher node running: this part is a node of that name serving both, with the rules of
``mrosd.tf.republish``. The Buffer (one subscription to /tf and /tf_static) is held only while a subscription
is: a daemon nobody asks for TF never decodes /tf.

A real tf2_web_republisher already running keeps the names (this part then does not start); one started later
takes the node name over (the master tells this node to shut down, and it does).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING, Any

from mrosd.actions.server import ActionServer, ServerGoal
from mrosd.errors import MasterError, MrosError
from mrosd.lograte import RateLimitedLog
from mrosd.msg import Time, get_message_class, get_service_class
from mrosd.tcpros.node import Node
from mrosd.tf.buffer import Buffer, transform_stamped
from mrosd.tf.republish import (
    GOAL_IDLE_TIMEOUT,
    Limits,
    Republisher,
    Subscription,
    Tick,
    check_request,
    clamp_timeout,
    topic_name,
)

if TYPE_CHECKING:
    from mrosd.tcpros import Publisher
    from mrosd.tcpros.admission import AdmissionLimits
    from mrosd.tf.core import Pose

__all__ = ["ACTION_TYPE", "NODE_NAME", "SERVICE_NAME", "TFRepublisherNode"]

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

NODE_NAME = "/tf2_web_republisher"
SERVICE_NAME = "/republish_tfs"
ACTION_TYPE = "tf2_web_republisher/TFSubscriptionAction"
#: tf2_web_republisher advertises each service topic latched with a queue of 10.
TOPIC_QUEUE = 10

TFArray = get_message_class("tf2_web_republisher/TFArray")
RepublishTFs = get_service_class("tf2_web_republisher/RepublishTFs")


class GoalEnded(MrosError):
    """A goal the republisher ends itself (its client is gone); the goal ends ABORTED with this text."""


class TFRepublisherNode:
    """The node ``/tf2_web_republisher``: the service, the action server and the subscriptions' tasks."""

    def __init__(
        self,
        master_uri: str,
        *,
        name: str = NODE_NAME,
        host: str | None = None,
        limits: Limits | None = None,
        goal_idle_timeout: float = GOAL_IDLE_TIMEOUT,
        admission: AdmissionLimits | None = None,
    ) -> None:
        self.node = Node(
            name, master_uri=master_uri, argv=[], rosout=False, logger_services=False, host=host, admission=admission
        )
        self.core = Republisher(limits or Limits())
        self.goal_idle_timeout = goal_idle_timeout
        self.buffer: Buffer | None = None
        #: False when another node already serves tf2_web_republisher's names
        self.serving = False
        self._action: ActionServer | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._watch: asyncio.Task[None] | None = None
        self._buffer_lock = asyncio.Lock()
        #: set each time a subscription is added or removed (for whoever waits on the count)
        self.changed = asyncio.Event()

    async def start(self) -> TFRepublisherNode:
        await self.node.start()
        try:
            other = await self._provider()
            if other:
                log.info("tf2_web_republisher: %s; mrosd's does not start", other)
                await self.node.aclose()
                return self
            await self.node.advertise_service(SERVICE_NAME, RepublishTFs, self._on_request)
            self._action = ActionServer(self.node, self.node.name, ACTION_TYPE, self._execute, simple=False)
            await self._action.start()
        except BaseException:
            await self.aclose()
            raise
        self.serving = True
        self._watch = asyncio.create_task(self._taken_over(), name="tf2_web_republisher shutdown watch")
        log.info("tf2_web_republisher: %s and the %s action, from mrosd's TF buffer", SERVICE_NAME, self.node.name)
        return self

    async def _provider(self) -> str:
        """Who already serves the names: a node of our name, or a ``/republish_tfs`` server ("" if none)."""
        master = self.node.master
        for lookup, what in ((master.lookup_node, self.node.name), (master.lookup_service, SERVICE_NAME)):
            with contextlib.suppress(MasterError):
                if await lookup(what):
                    return f"{what} is already registered"
        return ""

    async def _taken_over(self) -> None:
        await self.node.shutdown_event.wait()
        why = self.node.shutdown_reason
        log.info("tf2_web_republisher: shutdown by %s (another tf2_web_republisher started); mrosd's stops", why)
        self._watch = None
        await self.aclose()

    async def aclose(self) -> None:
        self.serving = False
        self.changed.set()
        if self._watch is not None:
            self._watch.cancel()
            self._watch = None
        if self._action is not None:
            await self._action.aclose()
            self._action = None
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self.buffer is not None:
            await self.buffer.aclose()
            self.buffer = None
        await self.node.aclose()

    async def __aenter__(self) -> TFRepublisherNode:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- the buffer, held while a subscription is ------------------------------------------------

    async def _hold_buffer(self) -> None:
        self.changed.set()
        async with self._buffer_lock:
            if self.buffer is None:
                self.buffer = await Buffer(self.node).start()

    async def _release_buffer(self) -> None:
        async with self._buffer_lock:
            if self.buffer is not None and not self.core.subscriptions:
                buffer, self.buffer = self.buffer, None
                await buffer.aclose()
        self.changed.set()

    def _lookup(self, target: str, source: str) -> Pose:
        assert self.buffer is not None
        return self.buffer.core.lookup(target, source, 0)[0]

    def _message(self, sub: Subscription, tick: Tick) -> list[Any]:
        for source, why in tick.broke:
            _ratelog.warning(f"tf repub {source}", "tf2_web_republisher: %s", why)
        for source in tick.recovered:
            log.info("tf2_web_republisher: transform from %s to %s is working again", source, sub.request.target_frame)
        now = Time.now().to_nsec()  # tf2_web_republisher stamps what it sends with the time of sending
        return [transform_stamped(sub.request.target_frame, source, now, pose) for source, pose in tick.transforms]

    async def _run(self, sub: Subscription, connections: Any, idle_timeout: float, send: Any) -> None:
        """Tick ``sub`` at its rate until it has had no subscriber for ``idle_timeout`` seconds."""
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(max(0.0, sub.next_wake() - loop.time()))
            now = loop.time()
            if sub.observe_subscribers(connections(), now, idle_timeout):
                return
            if now >= sub.next_tick and self.buffer is not None:
                transforms = self._message(sub, sub.tick(self._lookup, now))
                if transforms:
                    send(transforms)

    # --- the service: a topic per request --------------------------------------------------------

    async def _on_request(self, req: Any) -> Any:
        request = check_request(
            req.source_frames, req.target_frame, req.angular_thres, req.trans_thres, req.rate, limits=self.core.limits
        )
        timeout = clamp_timeout(req.timeout.secs + req.timeout.nsecs / 1e9, self.core.limits)
        sub = self.core.add(request, asyncio.get_running_loop().time(), timeout)
        name = topic_name(self.node.name, sub.id)
        try:
            await self._hold_buffer()
            pub = await self.node.advertise(name, TFArray, latch=True, queue_size=TOPIC_QUEUE)
        except BaseException:
            self.core.remove(sub.id)
            await self._release_buffer()
            raise
        self._spawn(self._serve_topic(sub, pub, timeout), f"tf2_web_republisher {name}")
        log.info("tf2_web_republisher: publishing requested TFs on topic %s", name)
        return RepublishTFs._response_class(topic_name=name)

    async def _serve_topic(self, sub: Subscription, pub: Publisher, timeout: float) -> None:
        try:
            await self._run(sub, pub.get_num_connections, timeout, lambda t: pub.publish_nowait(TFArray(transforms=t)))
            log.info("tf2_web_republisher: no subscribers on %s for %.1f s; unadvertising it", pub.topic, timeout)
        finally:
            self.core.remove(sub.id)
            await pub.aclose()
            await self._release_buffer()

    def _spawn(self, coro: Any, name: str) -> None:
        task = asyncio.create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # --- the action: a goal per subscription -----------------------------------------------------

    async def _execute(self, goal: ServerGoal) -> Any:
        g = goal.goal
        request = check_request(
            g.source_frames, g.target_frame, g.angular_thres, g.trans_thres, g.rate, limits=self.core.limits
        )
        sub = self.core.add(request, asyncio.get_running_loop().time())
        assert self._action is not None
        feedback_class = self._action.spec.feedback
        feedback_pub = self.node.publishers.get(f"{self._action.ns}/feedback")
        connections = feedback_pub.get_num_connections if feedback_pub is not None else (lambda: 1)
        try:
            await self._hold_buffer()
            await self._run(
                sub,
                connections,
                self.goal_idle_timeout,
                lambda t: goal.publish_feedback(feedback_class(transforms=t)),
            )
        finally:
            self.core.remove(sub.id)
            await self._release_buffer()
        raise GoalEnded(f"no subscriber to the feedback for {self.goal_idle_timeout:.0f} s: the client is gone")
