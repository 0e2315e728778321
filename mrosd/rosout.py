"""The built-in rosout aggregator: every message on ``/rosout`` is republished on ``/rosout_agg``.

roscore runs a ``/rosout`` node that does this; tools such as rqt_console and ``rostopic echo /rosout_agg``
expect it, so mrosd provides the same node inside the daemon. It is an ordinary user of the public Node API
and forwards the serialized bytes unchanged (raw mode both ways would need a raw publisher; decoding a
rosgraph_msgs/Log is cheap and keeps the publisher typed).

Drop policy: the aggregator never blocks a logger. The publisher's per-subscriber queues are bounded
(``QUEUE_SIZE``, drop-oldest, as documented for ``mrosd.Publisher``); a slow console loses old lines, not
the daemon its memory. The node name is ``/rosout``, as in roscore, so ``rosnode list`` looks familiar.

Like roscore's rosout (a roscpp node started with NoRosout) it publishes only /rosout_agg, offers
``/rosout/get_loggers`` and ``/rosout/set_logger_level``, writes every record to ``rosout.log`` in the
rosout node's line format when the daemon gives it a file (``mrosd.logfiles``), and on start sets the
parameters roscore's launch sets: ``/run_id`` (the run's log directory name), ``/rosversion`` (the ros_comm
release mrosd matches) and ``/rosdistro``, the last two with the trailing newline of the commands roslaunch
runs for them (``rosversion roslaunch``, ``rosversion -d``). ``/rosdistro`` follows ``rosversion -d``:
``$ROS_DISTRO`` when set (even empty), else what ``rosversion -d`` prints where ROS's tools are installed
(Debian's build says ``Debian``), else ``noetic``. roslaunch's own ``/roslaunch/uris/host_...`` entry is
not set: mrosd runs no roslaunch server for it to name (a roslaunch run adds its own).
"""

from __future__ import annotations

import asyncio
import logging
import os
import shutil
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from mrosd import backports
from mrosd.logfiles import RosoutLogFile
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
#: /rosdistro where neither ``$ROS_DISTRO`` nor ``rosversion`` says otherwise: the distribution mrosd matches.
DEFAULT_ROSDISTRO = "noetic"
#: Bound on asking ``rosversion -d``.
ROSVERSION_TIMEOUT = 5.0


def new_run_id() -> str:
    """A run id as roslaunch makes it (a uuid1): the /run_id parameter and the run's log directory name."""
    return str(uuid.uuid1())


def core_parameters(run_id: str, rosdistro: str) -> dict[str, str]:
    """The parameters roscore's launch sets, with the values roslaunch writes (command output keeps its newline)."""
    return {"/run_id": run_id, "/rosversion": ROSVERSION + "\n", "/rosdistro": rosdistro + "\n"}


async def rosdistro(environ: Mapping[str, str] | None = None) -> str:
    """What roscore's ``rosversion -d`` gives here: ``$ROS_DISTRO``, else the command's answer, else ``noetic``."""
    env = os.environ if environ is None else environ
    if "ROS_DISTRO" in env:  # as rosversion: set but empty still wins
        return env["ROS_DISTRO"]
    command = shutil.which("rosversion", path=env.get("PATH"))
    if command is None:
        return DEFAULT_ROSDISTRO
    try:
        proc = await asyncio.create_subprocess_exec(
            command,
            "-d",
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.DEVNULL,
            env=dict(env),
        )
    except OSError as exc:
        log.debug("rosversion -d did not start: %s", exc)
        return DEFAULT_ROSDISTRO
    try:
        async with backports.timeout(ROSVERSION_TIMEOUT):
            out, _ = await proc.communicate()
    except BaseException:
        proc.kill()
        await proc.wait()
        raise
    answer = out.decode(errors="replace").strip()
    return answer if proc.returncode == 0 and answer and "\n" not in answer else DEFAULT_ROSDISTRO


class RosoutAggregator:
    """The ``/rosout`` node: subscribes ``/rosout``, republishes on ``/rosout_agg``.

    Args:
        master_uri: the master to register with (the daemon passes its own).
        run_id: the /run_id to set (default: a fresh one).
        log_file: where to write rosout.log (None: no file).
        max_bytes, backups: rotation of ``log_file``.
        admission: caps on the node's inbound TCPROS connections (the daemon's TCPROS descriptor budget).
    """

    def __init__(
        self,
        master_uri: str,
        *,
        run_id: str | None = None,
        log_file: Path | None = None,
        max_bytes: int = 100 * 1024 * 1024,
        backups: int = 10,
        admission: AdmissionLimits | None = None,
    ) -> None:
        self.master_uri = master_uri
        self.run_id = run_id or new_run_id()
        self.log_path = log_file
        self._rotation = (max_bytes, backups)
        #: caps on the aggregator node's inbound TCPROS connections (the daemon passes its budget)
        self.admission = admission
        self.forwarded = 0
        self._node: Node | None = None
        self._pub: Publisher | None = None
        self._file: RosoutLogFile | None = None

    async def start(self) -> None:
        """Register the node, its subscription and its publication.

        Raises:
            MrosError: the master refused a registration.
        """
        log_cls = get_message_class("rosgraph_msgs/Log")
        distro = asyncio.ensure_future(rosdistro())  # a short subprocess, overlapping the registrations
        try:
            node = Node(NODE_NAME, master_uri=self.master_uri, argv=[], rosout=False, admission=self.admission)
            await node.__aenter__()
        except BaseException:
            distro.cancel()
            await asyncio.gather(distro, return_exceptions=True)
            raise
        self._node = node
        try:
            if self.log_path is not None:
                try:
                    self._file = RosoutLogFile(self.log_path, *self._rotation)
                except OSError as exc:  # the aggregator still republishes; the file is a convenience
                    log.error("rosout: cannot write %s: %s", self.log_path, exc.strerror or exc)
            await node.set_param("/run_id", self.run_id)
            self._pub = await node.advertise(OUT_TOPIC, log_cls, queue_size=QUEUE_SIZE)
            await node.subscribe(IN_TOPIC, log_cls, callback=self._forward)
            for key, value in core_parameters(self.run_id, await distro).items():
                if key != "/run_id":
                    await node.set_param(key, value)
        except BaseException:
            distro.cancel()
            await asyncio.gather(distro, return_exceptions=True)
            await self.aclose()
            raise

    async def _forward(self, msg: Any) -> None:
        pub = self._pub
        if pub is None:
            return
        if self._file is not None:
            try:
                self._file.write_record(msg)
            except Exception:  # a record that cannot be written must not stop the republishing
                log.debug("rosout: could not write a record to %s", self.log_path, exc_info=True)
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
        file, self._file = self._file, None
        if file is not None:
            file.close()

    async def __aenter__(self) -> RosoutAggregator:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
