"""The daemon's log files, where roscore writes them: ``<log dir>/<run_id>/master.log`` and ``rosout.log``.

People ``tail -f ~/.ros/log/latest/rosout.log``, attach it to bug reports and let ``rosclean check`` count
it, so mrosd writes the same files in the same places and formats as roscore:

- the log directory is ROS's (rospkg's ``get_log_dir``): ``$ROS_LOG_DIR``, else ``$ROS_HOME/log``, else
  ``~/.ros/log``; ``[log] dir`` in mrosd.toml replaces it, ``dir = "off"`` writes no files at all;
- each run gets ``<log dir>/<run_id>/`` (the run id is the ``/run_id`` parameter) and ``latest`` is pointed
  at it, replaced atomically (roslaunch removes and re-creates it; a ``latest`` that is not a symlink is left
  alone, as roslaunch leaves it);
- ``master.log`` holds the daemon's own log records in rosmaster's format
  (``[logger][LEVEL] 2026-11-25 20:51:03,601: message``) and, as rosmaster logs them, one line per
  registration change (``+PUB [/chatter] /talker http://host:port/``, ``-SUB ...``, ``+SERVICE ...``);
  those lines go to the file only, never to the journal;
- ``rosout.log`` holds every record the ``/rosout`` node receives, in the rosout node's line format
  (``rosout_line``), after rosout's start-up line.

Both files rotate when they pass ``[log] max_bytes`` (default 100 MiB, rosout's limit), keeping ``backups``
numbered copies (default 10, as rosout): ``rosout.log.1`` is the newest. So the disk a flood of log records
can take is bounded by ``max_bytes * (backups + 1)`` per file. A write that fails (disk full) is reported on
the journal at most once per 10 s, and the daemon goes on without it: log files never stop the master.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import logging.handlers
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from mrosd.lograte import RateLimitedLog

__all__ = [
    "MASTER_LOG_FORMAT",
    "RosoutLogFile",
    "RunLogs",
    "graph_lines",
    "ros_log_root",
    "rosout_line",
    "rosout_startup_line",
    "stamp_text",
]

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log, period=10.0, burst=1)

#: rosmaster's (rospy's python_logging.conf) line format for master.log.
MASTER_LOG_FORMAT = "[%(name)s][%(levelname)s] %(asctime)s: %(message)s"
#: The logger of the registration lines (``+PUB ...``): master.log only, not propagated to the journal.
GRAPH_LOGGER = "mrosd.master.graph"
#: rosout's names of rosgraph_msgs/Log levels; any other level is printed as its number.
LEVEL_TEXT = {1: "DEBUG", 2: "INFO", 4: "WARN", 8: "ERROR", 16: "FATAL"}
#: How long the graph follower waits for one change before asking again (bounded by the master anyway).
GRAPH_WAIT = 30.0


def ros_log_root(environ: Mapping[str, str] | None = None) -> Path:
    """ROS's log directory: ``$ROS_LOG_DIR``, else ``$ROS_HOME/log``, else ``~/.ros/log`` (rospkg's rule)."""
    env = os.environ if environ is None else environ
    if "ROS_LOG_DIR" in env:
        return Path(env["ROS_LOG_DIR"])
    if "ROS_HOME" in env:
        return Path(env["ROS_HOME"]) / "log"
    return Path(os.path.expanduser("~")) / ".ros" / "log"


def stamp_text(secs: int, nsecs: int) -> str:
    """A ``ros::Time`` as roscpp prints it: seconds, a dot, nine digits of nanoseconds."""
    return f"{secs}.{nsecs:09d}"


def rosout_startup_line(now_ns: int) -> str:
    """The lines the rosout node writes first into a new rosout.log (two blank lines, then the start time)."""
    secs, nsecs = divmod(now_ns, 1_000_000_000)
    return f"\n\n{stamp_text(secs, nsecs)}  Node Startup\n"


def rosout_line(msg: Any) -> str:
    """One rosgraph_msgs/Log (any object with its fields) as the rosout node writes it, newline included.

    ``1795639868.613579511 INFO /talker [talker.py:5(main)] [topics: /rosout, /chatter] hello``
    """
    stamp = msg.header.stamp
    where = f"[{msg.file}:{msg.line}({msg.function})]"
    topics = ", ".join(msg.topics)
    level = LEVEL_TEXT.get(msg.level, str(msg.level))
    return f"{stamp_text(stamp.secs, stamp.nsecs)} {level} {msg.name} {where} [topics: {topics}] {msg.msg}\n"


class _RotatingFile(logging.handlers.RotatingFileHandler):
    """``RotatingFileHandler`` whose write errors are one rate-limited journal line, not a traceback each."""

    def handleError(self, record: logging.LogRecord) -> None:
        import sys

        exc = sys.exc_info()[1]
        _ratelog.error("write", "cannot write %s: %s", self.baseFilename, exc)


class _NotOwnErrors(logging.Filter):
    """Keeps this module's own records (a failed write) out of the file that failed."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name != __name__


def _open(path: Path, max_bytes: int, backups: int, fmt: str) -> _RotatingFile:
    handler = _RotatingFile(path, maxBytes=max_bytes, backupCount=backups, encoding="utf-8", errors="replace")
    handler.setFormatter(logging.Formatter(fmt))
    handler.addFilter(_NotOwnErrors())
    return handler


class RosoutLogFile:
    """rosout.log: the start-up line, then one ``rosout_line`` per record, rotated by size.

    Writes are synchronous and flushed per line, as the rosout node's are (a local file, a short line).
    """

    def __init__(self, path: Path, max_bytes: int, backups: int) -> None:
        self.path = path
        self._handler = _open(path, max_bytes, backups, "%(message)s")
        self._handler.terminator = ""
        self.written = 0
        self._write(rosout_startup_line(time.time_ns()))

    def _write(self, text: str) -> None:
        self._handler.handle(logging.makeLogRecord({"msg": text, "levelno": logging.INFO}))

    def write_record(self, msg: Any) -> None:
        """Append one rosgraph_msgs/Log (any object with its fields)."""
        self._write(rosout_line(msg))
        self.written += 1

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # a failed last flush was reported already
            self._handler.close()


def graph_lines(old: Any, new: Any, api_of: Callable[[str], str]) -> list[str]:
    """rosmaster's registration lines for what changed between two ``getSystemState`` values.

    ``+PUB [/chatter] /talker http://host:port/``; removals (``-PUB``, ``-SUB``, ``-SERVICE``) first, as a
    node that re-registers is seen leaving before it comes back. ``api_of(node)`` gives a node's slave API.
    """
    out: list[str] = []
    kinds = ("PUB", "SUB", "SERVICE")
    pairs_old = [{(str(name), str(n)) for name, nodes in table for n in nodes} for table in old]
    pairs_new = [{(str(name), str(n)) for name, nodes in table for n in nodes} for table in new]
    for sign, first, second in (("-", pairs_old, pairs_new), ("+", pairs_new, pairs_old)):
        for kind, a, b in zip(kinds, first, second, strict=True):
            out.extend(f"{sign}{kind} [{name}] {node} {api_of(node)}".rstrip() for name, node in sorted(a - b))
    return out


class RunLogs:
    """One run's log directory: ``master.log`` attached to the ``mrosd`` logger, ``latest`` pointed at it.

    Args:
        root: the log directory (``ros_log_root()`` or ``[log] dir``).
        run_id: the run's id (the ``/run_id`` parameter): the directory's name.
        max_bytes, backups: rotation of each file.
    """

    def __init__(self, root: Path, run_id: str, max_bytes: int, backups: int) -> None:
        self.root = root
        self.run_id = run_id
        self.dir = root / run_id
        self.max_bytes = max_bytes
        self.backups = backups
        self._master: _RotatingFile | None = None
        self._graph: logging.Logger | None = None
        self._follower: asyncio.Task[None] | None = None

    @property
    def rosout_path(self) -> Path:
        return self.dir / "rosout.log"

    @property
    def master_path(self) -> Path:
        return self.dir / "master.log"

    def open(self, level: int = logging.INFO) -> None:
        """Create the directory, point ``latest`` at it and start writing master.log.

        Raises:
            OSError: the directory cannot be created or master.log cannot be opened.
        """
        self.dir.mkdir(parents=True, exist_ok=True)
        self._point_latest()
        handler = _open(self.master_path, self.max_bytes, self.backups, MASTER_LOG_FORMAT)
        handler.setLevel(level)
        self._master = handler
        logging.getLogger("mrosd").addHandler(handler)
        graph = logging.getLogger(GRAPH_LOGGER)
        graph.propagate = False  # master.log only: the journal keeps the daemon's own messages
        graph.setLevel(logging.INFO)
        graph.addHandler(handler)
        self._graph = graph

    def _point_latest(self) -> None:
        latest = self.root / "latest"
        if latest.exists() and not latest.is_symlink():
            log.warning("%s is not a symlink; leaving it alone (as roslaunch does)", latest)
            return
        tmp = self.root / f".latest.{os.getpid()}"
        try:
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.dir)
            tmp.replace(latest)  # atomic: a reader sees the old run or the new one, never no ``latest``
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            log.warning("cannot point %s at %s: %s", latest, self.dir, exc.strerror or exc)

    def follow_graph(self, api: Any) -> None:
        """Write rosmaster's ``+PUB``/``-SUB``/... lines for the in-process master ``api`` (a ``MasterApi``)."""
        if self._graph is not None and self._follower is None:
            self._follower = asyncio.get_running_loop().create_task(self._follow(api, self._graph), name="master.log")

    @staticmethod
    async def _follow(api: Any, graph: logging.Logger) -> None:
        apis: dict[str, str] = {}

        def api_of(node: str) -> str:
            uri = api.registry.lookup_node(node)
            if uri:
                apis[node] = uri
            return apis.get(node, "")

        version = -1
        state: list[Any] = [[], [], []]
        while True:
            code, _, value = await api.wait_system_state_change("/mrosd", version, GRAPH_WAIT)
            if code != 1:  # too many watchers (never for the daemon itself): try again later
                await asyncio.sleep(1.0)
                continue
            version, new_state, _types = value
            for text in graph_lines(state, new_state, api_of):
                graph.info("%s", text)
            state = new_state
            # remembered only while a node is listed: anonymous CLI nodes come and go all day
            listed = {str(n) for table in state for _name, nodes in table for n in nodes}
            for node in apis.keys() - listed:
                del apis[node]

    async def aclose(self) -> None:
        """Stop following the graph and close master.log (the daemon's last part to close)."""
        if self._follower is not None:
            self._follower.cancel()
            await asyncio.gather(self._follower, return_exceptions=True)
            self._follower = None
        if self._master is not None:
            logging.getLogger("mrosd").removeHandler(self._master)
            if self._graph is not None:
                self._graph.removeHandler(self._master)
            with contextlib.suppress(OSError, ValueError):
                self._master.close()
            self._master = None
