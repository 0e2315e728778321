"""A node's side of /rosout: a ``logging`` handler publishing rosgraph_msgs/Log, and the logger services.

As in rospy, records logged on the ``rosout`` logger and its children reach /rosout: ``node.log`` is the
node's own child (``rosout./ns/talker``), and records logged on plain ``rosout`` (the logger rospy code
uses) go out through every node of the process that publishes /rosout (one, in the usual one-node
process). Other loggers (``mrosd.*`` included) stay local, so the library's own diagnostics never loop
back through the topic. Levels map as rospy maps them (DEBUG 1, INFO 2, WARNING 4, ERROR 8, CRITICAL 16;
levels in between round down); the Log carries the node's name, the record's file, function and line, and
the node's topics. The publisher is latched with a queue of 100, as rospy's.

``~get_loggers`` and ``~set_logger_level`` (roscpp/GetLoggers, roscpp/SetLoggerLevel, as every rospy and
roscpp node offers them) list Python's loggers with their effective levels and set one logger's level, so
``rosconsole list``/``rqt_logger_level`` work on our nodes and on the daemon's /rosout.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mrosd.msg import Time, get_message_class, get_service_class

if TYPE_CHECKING:
    from mrosd.tcpros.publisher import Publisher

#: The logger whose records (its own and its children's) are published on /rosout, as in rospy.
ROSOUT_LOGGER = "rosout"
TOPIC = "/rosout"
#: rospy's /rosout publisher: latched, queue of 100.
QUEUE_SIZE = 100

_LOG_LEVELS = ((logging.CRITICAL, 16), (logging.ERROR, 8), (logging.WARNING, 4), (logging.INFO, 2))
#: roscpp's level names (SetLoggerLevel takes them in any case) <-> logging levels.
LEVEL_NAMES = {"debug": logging.DEBUG, "info": logging.INFO, "warn": logging.WARNING, "error": logging.ERROR}
LEVEL_NAMES["fatal"] = logging.CRITICAL


def log_level_byte(levelno: int) -> int:
    """rosgraph_msgs/Log's level for a ``logging`` level: the highest ROS level not above it."""
    for threshold, value in _LOG_LEVELS:
        if levelno >= threshold:
            return value
    return 1


def level_name(levelno: int) -> str:
    """roscpp's name for a logging level (GetLoggers answers these)."""
    for name, value in sorted(LEVEL_NAMES.items(), key=lambda kv: -kv[1]):
        if levelno >= value:
            return name
    return "debug"


def node_logger(node_name: str) -> logging.Logger:
    """The logger a node's records go to /rosout through: ``rosout.<node name>``."""
    return logging.getLogger(f"{ROSOUT_LOGGER}.{node_name}")


class RosoutHandler(logging.Handler):
    """Publishes records of ``rosout`` and of its node's logger as rosgraph_msgs/Log.

    Thread-safe: a record emitted from another thread is handed to the node's event loop. A record logged
    while this handler publishes (a log line from inside the publish path) is not published again.
    """

    def __init__(
        self,
        node_name: str,
        publisher: Publisher,
        topics: Callable[[], list[str]],
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        super().__init__(logging.DEBUG)
        self.node_name = node_name
        self.own_logger = node_logger(node_name).name
        self.publisher = publisher
        self.topics = topics
        self.loop = loop
        self.log_class: Any = get_message_class("rosgraph_msgs/Log")
        self._busy = threading.local()
        self.published = 0

    def _mine(self, name: str) -> bool:
        if name == ROSOUT_LOGGER:
            return True
        own = self.own_logger
        if name == own or name.startswith(own + "."):
            return True
        # Another node's logger (rosout./other) is that node's to publish; other children (rosout.camera) are ours.
        return not name.startswith(ROSOUT_LOGGER + "./")

    def emit(self, record: logging.LogRecord) -> None:
        if not self._mine(record.name) or getattr(self._busy, "on", False):
            return
        try:
            text = self.format(record)
        except Exception:
            self.handleError(record)
            return
        fields = (log_level_byte(record.levelno), text, record.filename, record.funcName or "", record.lineno)
        args = (fields, record.created)
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is self.loop:
            self._publish(*args)
        elif not self.loop.is_closed():
            try:
                self.loop.call_soon_threadsafe(self._publish, *args)
            except RuntimeError:  # the loop closed meanwhile: the record is dropped, as after shutdown
                pass

    def _publish(self, fields: tuple[int, str, str, str, int], created: float) -> None:
        # On the loop's thread: the node's topic tables are read where they are changed.
        if self.publisher.closed:
            return
        self._busy.on = True
        try:
            level, text, file, function, line = fields
            msg = self.log_class(level=level, name=self.node_name, msg=text, file=file, function=function, line=line)
            msg.topics = self.topics()
            msg.header.stamp = Time.from_sec(created)
            self.publisher.publish_nowait(msg)
            self.published += 1
        except Exception:
            pass  # never let logging fail the caller; the local handlers still have the record
        finally:
            self._busy.on = False


def get_loggers() -> list[tuple[str, str]]:
    """Every Python logger known to ``logging`` (root first) with roscpp's name of its effective level."""
    manager = logging.Logger.manager
    names = sorted(n for n, lg in manager.loggerDict.items() if isinstance(lg, logging.Logger))
    root = logging.getLogger()
    out = [("root", level_name(root.getEffectiveLevel()))]
    out.extend((n, level_name(logging.getLogger(n).getEffectiveLevel())) for n in names)
    return out


def set_logger_level(name: str, level: str) -> None:
    """Set one logger's level by roscpp's level name.

    Raises:
        ValueError: the level name is not one of debug, info, warn, error, fatal.
    """
    levelno = LEVEL_NAMES.get(level.strip().lower())
    if levelno is None:
        raise ValueError(f"unknown logger level [{level}]: use one of {', '.join(LEVEL_NAMES)}")
    logging.getLogger(None if name in ("", "root") else name).setLevel(levelno)


def logger_service_handlers() -> tuple[Any, Callable[[Any], Any], Any, Callable[[Any], Any]]:
    """(GetLoggers class, handler, SetLoggerLevel class, handler) for ``advertise_service``."""
    get_srv: Any = get_service_class("roscpp/GetLoggers")
    set_srv: Any = get_service_class("roscpp/SetLoggerLevel")
    logger_cls: Any = get_message_class("roscpp/Logger")

    def on_get(_req: Any) -> Any:
        return get_srv._response_class(loggers=[logger_cls(name=n, level=lv) for n, lv in get_loggers()])

    def on_set(req: Any) -> Any:
        set_logger_level(req.logger, req.level)  # ValueError -> the caller gets the text as the service error
        return set_srv._response_class()

    return get_srv, on_get, set_srv, on_set
