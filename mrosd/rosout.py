"""The built-in rosout aggregator: every message on ``/rosout`` is republished on ``/rosout_agg``.

roscore runs a ``/rosout`` node that does this; tools such as rqt_console and ``rostopic echo /rosout_agg``
expect it, so mrosd provides the same node inside the daemon. It is an ordinary user of the public Node API
and forwards the serialized bytes unchanged (raw mode both ways would need a raw publisher; decoding a
rosgraph_msgs/Log is cheap and keeps the publisher typed).

Drop policy: the aggregator never blocks a logger. The publisher's per-subscriber queues are bounded
(``QUEUE_SIZE``, drop-oldest, as documented for ``mrosd.Publisher``); a slow console loses old lines, not
the daemon its memory. The node name is ``/rosout``, as in roscore, so ``rosnode list`` looks familiar.

Like roscore's rosout (a roscpp node started with NoRosout) it publishes only /rosout_agg, offers
``/rosout/get_loggers`` and ``/rosout/set_logger_level``, and on start sets the parameters roscore's launch
sets: ``/run_id`` (a fresh uuid1), ``/rosdistro`` (``$ROS_DISTRO``, else ``noetic``) and ``/rosversion``
(the ros_comm release mrosd matches), the last two with the trailing newline of the commands roslaunch runs
for them (``rosversion -d``, ``rosversion roslaunch``).
"""

from __future__ import annotations

import logging
import os
import uuid
from collections.abc import Mapping
from typing import Any

from mrosd.msg import get_message_class
from mrosd.tcpros import Node, Publisher
from mrosd.tcpros.admission import AdmissionLimits

log = logging.getLogger(__name__)

#: Per-subscriber queue on /rosout_agg; a console that falls this far behind loses the oldest lines.
QUEUE_SIZE = 1000

NODE_NAME = "rosout"
IN_TOPIC = "/rosout"
OUT_TOPIC = "/rosout_agg"
#: The ros_comm release whose behaviour mrosd matches (roscore's /rosversion).
ROSVERSION = "1.15.15"
DEFAULT_ROSDISTRO = "noetic"


def core_parameters(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The parameters roscore's launch sets: /run_id, /rosdistro, /rosversion (values as roslaunch writes them)."""
    env = os.environ if environ is None else environ
    return {
        "/run_id": str(uuid.uuid1()),
        "/rosdistro": (env.get("ROS_DISTRO") or DEFAULT_ROSDISTRO) + "\n",
        "/rosversion": ROSVERSION + "\n",
    }


class RosoutAggregator:
    """The ``/rosout`` node: subscribes ``/rosout``, republishes on ``/rosout_agg``.

    Args:
        master_uri: the master to register with (the daemon passes its own).
        admission: caps on the node's inbound TCPROS connections (the daemon's TCPROS descriptor budget).
    """

    def __init__(self, master_uri: str, *, admission: AdmissionLimits | None = None) -> None:
        self.master_uri = master_uri
        #: caps on the aggregator node's inbound TCPROS connections (the daemon passes its budget)
        self.admission = admission
        self.forwarded = 0
        self._node: Node | None = None
        self._pub: Publisher | None = None

    async def start(self) -> None:
        """Register the node, its subscription and its publication.

        Raises:
            MrosError: the master refused a registration.
        """
        log_cls = get_message_class("rosgraph_msgs/Log")
        node = Node(NODE_NAME, master_uri=self.master_uri, argv=[], rosout=False, admission=self.admission)
        await node.__aenter__()
        self._node = node
        try:
            for key, value in core_parameters().items():
                await node.set_param(key, value)
            self._pub = await node.advertise(OUT_TOPIC, log_cls, queue_size=QUEUE_SIZE)
            await node.subscribe(IN_TOPIC, log_cls, callback=self._forward)
        except BaseException:
            await self.aclose()
            raise

    async def _forward(self, msg: Any) -> None:
        pub = self._pub
        if pub is None:
            return
        try:
            await pub.publish(msg)
        except Exception:
            # A bad record or a closing publisher must not end the subscription.
            log.exception("rosout: could not forward a message to %s", OUT_TOPIC)
            return
        self.forwarded += 1

    async def aclose(self) -> None:
        """Unregister and close the node."""
        node, self._node = self._node, None
        if node is not None:
            await node.__aexit__(None, None, None)

    async def __aenter__(self) -> RosoutAggregator:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
