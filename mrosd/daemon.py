"""``mrosd``: the service users run. One event loop holding the master, the IXM registry and rosout.

This module owns the process: command line, configuration loading, logging format, the event loop (uvloop
when installed), POSIX signals and the systemd protocol. The parts it composes (``mrosd.master.Master``,
``mrosd.ixm.server.IxmServer``, ``mrosd.rosout.RosoutAggregator``) are embeddable servers with
``start()``/``aclose()`` and know nothing of signals or systemd.

Lifecycle, as systemd sees it (``Type=notify``):
  1. raise the soft descriptor limit to the hard one; start the master and check it answers ``getPid``
     over XML-RPC (if not: exit 1); then IXM, its topic bridges, rosout and web (the Foxglove WebSocket
     server, loopback unless a token is set), each of which may fail alone:
     one error line naming the part and why, and the daemon runs degraded (``--strict``: exit 1);
  2. send ``READY=1`` with a status line (``running: ...`` or ``degraded: ...``); ping ``WATCHDOG=1`` at
     half ``WATCHDOG_USEC`` while the master still answers its own ``getPid``;
  3. ``SIGHUP`` re-reads the file, reloads the IXM access rules (other sections need a restart) and starts
     again the parts that failed to start; any error keeps the running configuration;
  4. ``SIGTERM``/``SIGINT`` send ``STOPPING=1`` and close the parts in reverse order within
     ``SHUTDOWN_TIMEOUT`` seconds (the IXM server removes its socket), then exit 0. Signals arrive on a
     thread of their own, so a blocked event loop cannot hold the process past the deadline.

Exit codes: 0 clean stop, 1 runtime failure (a port in use, a part failed to start under ``--strict``, a part
that did not close in time), 2 bad configuration or usage.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import resource
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mrosd.config import Config, load_config, part_options
from mrosd.errors import ConfigError, MrosError
from mrosd.fdbudget import FdBudgets, fd_budgets
from mrosd.loop import event_loop_factory
from mrosd.sdnotify import Notifier, watchdog_interval

if TYPE_CHECKING:
    from mrosd.fleet.bridge import FleetBridge
    from mrosd.ixm.bridge import Bridge, IxmBridge
    from mrosd.ixm.rules import AccessRules
    from mrosd.ixm.server import IxmServer
    from mrosd.logfiles import RunLogs
    from mrosd.master import Master
    from mrosd.rosout import RosoutAggregator
    from mrosd.tcpros.admission import AdmissionLimits
    from mrosd.web.server import WebServer
    from mrosd.xmlrpc import XmlRpcClient

log = logging.getLogger("mrosd")

#: Upper bound on a clean shutdown; systemd's TimeoutStopSec in the unit is larger (10 s) so that we, not
#: SIGKILL, decide what is left behind.
SHUTDOWN_TIMEOUT = 5.0

#: After SHUTDOWN_TIMEOUT plus this, a shutdown that is still not done (a part blocks the event loop) is
#: cut short from the signal thread: the IXM socket is unlinked and the process exits 1.
HARD_STOP_GRACE = 1.0

#: How long the start-up self-check waits for the master to answer its first getPid.
READY_TIMEOUT = 10.0

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2

# syslog priorities for journald's "<N>" line prefix (sd-daemon.h).
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class JournalFormatter(logging.Formatter):
    """``<6>mrosd.master: message``: journald reads the priority prefix and adds its own timestamp."""

    def format(self, record: logging.LogRecord) -> str:
        priority = _PRIORITY.get(record.levelno, 6 if record.levelno < logging.WARNING else 4)
        text = super().format(record)
        return "\n".join(f"<{priority}>{line}" for line in text.splitlines() or [""])


def setup_logging(level: str, environ: dict[str, str] | None = None) -> None:
    """Log to stderr: journald style under systemd (``$JOURNAL_STREAM`` set), timestamped otherwise."""
    env = os.environ if environ is None else environ
    handler = logging.StreamHandler(sys.stderr)
    if env.get("JOURNAL_STREAM"):
        handler.setFormatter(JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())


def reason(exc: BaseException) -> str:
    """One line saying why, for a log line or STATUS: our own errors carry it, others get their type named."""
    if isinstance(exc, MrosError):
        text = str(exc)
    elif isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    else:
        text = f"{type(exc).__name__}: {exc}"
    return " ".join(text.split()) or type(exc).__name__


def _nofile_target(soft: int, hard: int) -> int:
    """The soft RLIMIT_NOFILE the daemon runs with: the hard limit, capped at the kernel's ``nr_open``."""
    target = hard
    if hard == resource.RLIM_INFINITY:
        try:
            with open("/proc/sys/fs/nr_open", encoding="ascii") as f:
                target = int(f.read())
        except (OSError, ValueError):
            target = max(soft, 65536) if soft != resource.RLIM_INFINITY else soft
    return target


def planned_budgets() -> FdBudgets:
    """The descriptor budgets the daemon would run with, from the limit it would raise itself to."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = _nofile_target(soft, hard)
    limit = soft if soft == resource.RLIM_INFINITY or soft >= target else target
    return fd_budgets(1 << 20 if limit == resource.RLIM_INFINITY else limit)


def raise_nofile_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard limit (capped at the kernel's ``nr_open``); return the result.

    Every client connection and every IXM key costs the daemon descriptors; distributions still start
    services with a soft limit of 1024 although the hard limit allows far more.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = _nofile_target(soft, hard)
    if soft == resource.RLIM_INFINITY or soft >= target:
        log.info("open files: %s", "unlimited" if soft == resource.RLIM_INFINITY else soft)
        return soft
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    except (OSError, ValueError) as exc:
        log.warning("open files: %d (could not raise it to %d: %s)", soft, target, reason(exc))
        return soft
    log.info("open files: %d (soft limit raised from %d)", target, soft)
    return target


def local_master_uri(cfg: Config, port: int) -> str:
    """The URI this process uses to reach its own master (loopback when it listens on every address)."""
    host = cfg.master.host
    if host in ("", "0.0.0.0", "::"):
        host = "127.0.0.1" if host != "::" else "::1"
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}/"


def load_ixm_rules(raw: dict[str, Any], source: str = "") -> AccessRules:
    """Parse the opaque ``[ixm.rules]`` table with the IXM part's parser (ConfigError naming the key)."""
    from mrosd.ixm.rules import parse_rules

    return parse_rules(raw, f"{source}: ixm.rules" if source else "ixm.rules")


def load_bridges(raw: dict[str, Any], source: str = "") -> list[Bridge]:
    """The ``[ixm.rules.bridges]`` table (ConfigError naming the key)."""
    from mrosd.ixm.bridge import parse_bridges

    return parse_bridges(raw, f"{source}: ixm.rules" if source else "ixm.rules")


class Daemon:
    """The composed parts and their lifecycle; ``run()`` owns the loop's signals and the systemd protocol.

    The master is the part every node needs, so only the master failing to start is fatal. IXM, its
    topic bridges and rosout failing to start is logged in one line naming the part and the reason and
    leaves the daemon running degraded (``STATUS=degraded: ...``), unless ``strict`` makes it fatal.
    """

    def __init__(
        self, cfg: Config, *, master_only: bool = False, strict: bool = False, notifier: Notifier | None = None
    ) -> None:
        self.cfg = cfg
        self.master_only = master_only
        self.strict = strict
        self.notifier = notifier if notifier is not None else Notifier()
        self.master: Master | None = None
        self.ixm: IxmServer | None = None
        self.bridge: IxmBridge | None = None
        self.rosout: RosoutAggregator | None = None
        #: this run's log files (``<log dir>/<run_id>/``), None when ``[log] dir = "off"`` or not writable
        self.logs: RunLogs | None = None
        self.run_id = ""
        self.web: WebServer | None = None
        self.fleet: FleetBridge | None = None
        self.master_uri = ""
        #: each part's share of RLIMIT_NOFILE, given to it as its cap (``mrosd.fdbudget``); set by ``start()``
        self.budgets: FdBudgets | None = None
        #: part name -> why it did not start (the daemon runs degraded without it)
        self.failed: dict[str, str] = {}
        self._parts: list[tuple[str, Any]] = []
        self._xmlrpc: XmlRpcClient | None = None

    async def start(self) -> None:
        """Start every configured part; on a fatal failure the parts already started are closed again.

        Raises:
            OSError: the master's socket could not be bound (port in use, permission).
            MrosError: the master does not answer, or (``strict``) another part refused to start.
        """
        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
        self.budgets = fd_budgets(1 << 20 if soft == resource.RLIM_INFINITY else soft)
        try:
            self._open_logs()
            await self._start_master()
            if self.logs is not None and self.master is not None:
                self.logs.follow_graph(self.master.api)
            await self._wait_master_answers()
            if not self.master_only and self.cfg.ixm.enabled:
                await self._optional("ixm", self._start_ixm)
                if self.ixm is not None:
                    await self._optional("ixm-bridge", self._start_bridges)
            if not self.master_only and self.cfg.rosout.enabled:
                await self._optional("rosout", self._start_rosout)
            if not self.master_only and self.cfg.web.enabled:
                await self._optional("web", self._start_web)
            if not self.master_only and self.cfg.fleet.enabled:
                await self._optional("fleet", self._start_fleet)
            if not self.master_only and self.cfg.ros2.enabled:
                await self._optional("ros2", self._start_ros2)
        except BaseException:
            await self.aclose()
            raise

    async def _optional(self, name: str, starter: Callable[[], Any]) -> None:
        try:
            await starter()
        except Exception as exc:
            why = reason(exc)
            if self.strict:
                raise MrosError(f"{name}: {why}") from exc
            log.error("%s did not start: %s; the master keeps running without it", name, why)
            if not isinstance(exc, (MrosError, OSError)):
                log.debug("%s start failure", name, exc_info=exc)
            self.failed[name] = why

    def _open_logs(self) -> None:
        """master.log (and later rosout.log) in ``<log dir>/<run_id>/``; a log directory that cannot be
        written is one error line, never a reason to stop (the journal still has the daemon's messages)."""
        from mrosd.logfiles import RunLogs, ros_log_root
        from mrosd.rosout import new_run_id

        self.run_id = new_run_id()
        cfg = self.cfg.log
        if cfg.dir == cfg.OFF:
            return
        logs = RunLogs(Path(cfg.dir) if cfg.dir else ros_log_root(), self.run_id, cfg.max_bytes, cfg.backups)
        try:
            logs.open(logging.NOTSET)  # the loggers' levels ([log] level) decide, as for the journal
        except OSError as exc:
            log.error("no log files: cannot write %s: %s", logs.dir, reason(exc))
            return
        self.logs = logs
        self._parts.append(("logs", logs))  # first in, last out: master.log sees the whole shutdown
        log.info("log files in %s", logs.dir)

    async def _start_master(self) -> None:
        from mrosd.master import Master
        from mrosd.master.httpserver import MAX_CONNECTIONS, MAX_CONNECTIONS_PER_HOST

        allow = list(self.cfg.master.allow) or None
        options = part_options(self.cfg.master)
        if self.budgets is not None:  # the budget caps the master; one address never gets all of it
            cap = min(options.get("max_connections", MAX_CONNECTIONS), self.budgets.master)
            options["max_connections"] = cap
            per_host = options.get("max_connections_per_host", MAX_CONNECTIONS_PER_HOST)
            options["max_connections_per_host"] = min(per_host, max(1, cap * 3 // 4))
        master = Master(self.cfg.master.host, self.cfg.master.port, allow=allow, **options)
        await master.start()
        self.master = master
        self._parts.append(("master", master))
        self.master_uri = local_master_uri(self.cfg, int(master.port))
        log.info("master listening on %s:%d (%s)", self.cfg.master.host, master.port, self.master_uri)

    async def _wait_master_answers(self) -> None:
        from mrosd.xmlrpc import XmlRpcClient

        self._xmlrpc = XmlRpcClient(timeout=2.0)
        deadline = asyncio.get_running_loop().time() + READY_TIMEOUT
        while True:
            try:
                await self._xmlrpc.call(self.master_uri, "getPid", "/mrosd", timeout=2.0)
                return
            except MrosError as exc:
                if asyncio.get_running_loop().time() > deadline:
                    raise MrosError(f"the master does not answer at {self.master_uri}: {exc}") from exc
                await asyncio.sleep(0.05)

    async def _start_ixm(self) -> None:
        from mrosd.ixm.server import IxmServer

        rules = load_ixm_rules(self.cfg.ixm.rules, self.cfg.source)
        options = part_options(self.cfg.ixm)
        if self.budgets is not None:  # IXM's own split of a limit keeps 3/4 of it: hand it 4/3 of its budget
            from mrosd.ixm.resources import Limits

            shares = Limits.for_fd_limit(self.budgets.ixm * 4 // 3)
            for name in Limits.__struct_fields__:
                options.setdefault(name, getattr(shares, name))
        server = IxmServer(self.cfg.ixm.socket, rules, **options)
        await server.start()  # creates and checks the socket's directory
        self.ixm = server
        self._parts.append(("ixm", server))
        log.info("IXM registry listening on %s", self.cfg.ixm.socket)

    async def _start_bridges(self) -> None:
        bridges = load_bridges(self.cfg.ixm.rules, self.cfg.source)
        if not bridges:
            return
        from mrosd.ixm.bridge import IxmBridge

        bridge = IxmBridge(self.cfg.ixm.socket, self.master_uri, bridges, admission=self._tcpros_admission())
        await bridge.start()
        self.bridge = bridge
        self._parts.append(("ixm-bridge", bridge))

    async def _start_rosout(self) -> None:
        from mrosd.rosout import RosoutAggregator

        logs, cfg = self.logs, self.cfg.log
        agg = RosoutAggregator(
            self.master_uri,
            run_id=self.run_id or None,
            log_file=logs.rosout_path if logs is not None else None,
            max_bytes=cfg.max_bytes,
            backups=cfg.backups,
            admission=self._tcpros_admission(),
        )
        await agg.start()
        self.rosout = agg
        self._parts.append(("rosout", agg))
        log.info("rosout aggregator running (/rosout -> /rosout_agg)")

    def _tcpros_admission(self) -> AdmissionLimits | None:
        """Inbound TCPROS caps of one in-daemon node (rosout aggregator, bridges): half the TCPROS budget each."""
        if self.budgets is None:
            return None
        from mrosd.tcpros.admission import AdmissionLimits

        cap = max(1, self.budgets.tcpros // 2)
        return AdmissionLimits(
            max_connections=cap,
            max_pending=max(1, min(256, cap // 2)),
            max_pending_per_address=max(1, min(128, cap // 4)),
        )

    async def _start_web(self) -> None:
        from mrosd.web.access import AccessPolicy
        from mrosd.web.foxglove_server import SessionLimits
        from mrosd.web.server import WebServer

        web = self.cfg.web
        policy = AccessPolicy(
            topics=web.topics, services=web.services, params=web.params, assets=web.assets, token=web.token
        )
        caps = {"queue_bytes": web.queue_bytes, "client_bytes": web.client_bytes}
        limits = SessionLimits(**{k: v for k, v in caps.items() if v is not None})
        rosbridge = web.rosbridge_port if web.rosbridge_port >= 0 else None
        server = WebServer(
            self.master_uri,
            host=web.host,
            port=web.foxglove_port,
            policy=policy,
            limits=limits,
            rosbridge_port=rosbridge,
            max_queued_bytes=web.total_bytes,
            asset_bytes=web.asset_bytes,
        )
        if web.max_clients is not None:
            server.max_clients = web.max_clients
        if self.budgets is not None:  # half the web budget for clients' sockets, half for the hub's TCPROS links
            server.max_clients = max(1, min(server.max_clients, self.budgets.web // 2))
        await server.start()
        self.web = server
        self._parts.append(("web", server))

    async def _start_fleet(self) -> None:
        from mrosd.fleet.bridge import FleetBridge
        from mrosd.fleet.options import fleet_options

        fleet = FleetBridge(fleet_options(self.cfg.fleet, self.cfg.source or "configuration"), self.master_uri)
        await fleet.start()
        self.fleet = fleet
        self._parts.append(("fleet", fleet))
        log.info("fleet: robot %s linked over Zenoh", self.cfg.fleet.robot)

    async def _start_ros2(self) -> None:
        from mrosd.ros2.bridge import Ros2Bridge, ros2_options

        ros2 = Ros2Bridge(ros2_options(self.cfg.ros2), self.master_uri)
        await ros2.start()
        self._parts.append(("ros2", ros2))

    def status_line(self) -> str:
        """The one-line status for ``systemctl status``: ``running: ...`` or ``degraded: ...; ixm failed: why``."""
        parts = [f"master {self.master_uri}"]
        if self.ixm is not None:
            parts.append(f"ixm {self.cfg.ixm.socket}")
        if self.bridge is not None:
            parts.append(f"{len(self.bridge.bridges)} ixm bridge(s)")
        if self.rosout is not None:
            parts.append("rosout")
        if self.web is not None:
            parts.append(f"foxglove {' '.join(self.web.urls)}")
            if self.web.rosbridge_port is not None:
                parts.append(f"rosbridge {' '.join(self.web.rosbridge_urls)}")
        if self.fleet is not None:
            parts.append(f"fleet {self.cfg.fleet.robot}")
        line = ", ".join(parts)
        if not self.failed:
            return "running: " + line
        return "degraded: " + line + "; " + "; ".join(f"{name} failed: {why}" for name, why in self.failed.items())

    async def master_alive(self, timeout: float) -> bool:
        """True when the master answers ``getPid`` within ``timeout`` seconds (the watchdog's health check)."""
        if self._xmlrpc is None:
            return False
        try:
            await self._xmlrpc.call(self.master_uri, "getPid", "/mrosd", timeout=timeout)
        except MrosError:
            return False
        return True

    async def reload(self, cfg: Config) -> None:
        """Apply a re-read configuration: IXM access rules now, and the parts that failed to start are tried
        again; other changes are logged as needing a restart.

        Raises:
            ConfigError: the new rules do not parse (the running ones stay).
        """
        rules = load_ixm_rules(cfg.ixm.rules, cfg.source)
        old = self.cfg
        if (cfg.master, cfg.rosout, cfg.web) != (old.master, old.rosout, old.web) or cfg.ixm.socket != old.ixm.socket:
            log.warning("SIGHUP: only [ixm.rules] is reloaded; restart mrosd to apply the other changes")
        if cfg.ixm.rules.get("bridges") != old.ixm.rules.get("bridges"):
            log.warning("SIGHUP: [ixm.rules.bridges] changed; restart mrosd to apply it")
        if cfg.fleet != old.fleet:
            log.warning("SIGHUP: [fleet] changed; restart mrosd to apply it")
        if self.ixm is not None:
            self.ixm.reload_rules(rules)
            log.info("SIGHUP: IXM access rules reloaded from %s", cfg.source or "defaults")
        self.cfg.ixm.rules = cfg.ixm.rules
        if self.failed:
            await self._retry_failed()

    async def _retry_failed(self) -> None:
        """Start again the parts that did not start (the operator fixed the cause and sent SIGHUP).

        The master keeps running meanwhile, so its registrations and parameters survive the repair.
        """
        retry, self.failed = self.failed, {}
        log.info("SIGHUP: starting again %s", ", ".join(retry))
        if "ixm" in retry:
            await self._optional("ixm", self._start_ixm)
        if self.ixm is not None and ("ixm" in retry or "ixm-bridge" in retry):
            await self._optional("ixm-bridge", self._start_bridges)
        if "rosout" in retry:
            await self._optional("rosout", self._start_rosout)
        if "web" in retry:
            await self._optional("web", self._start_web)
        if "fleet" in retry:
            await self._optional("fleet", self._start_fleet)
        if "ros2" in retry:
            await self._optional("ros2", self._start_ros2)

    async def aclose(self, timeout: float = SHUTDOWN_TIMEOUT) -> bool:
        """Close the parts in reverse start order within ``timeout`` seconds in all; True when all closed.

        Each part gets a fair share of the time left, so one part that hangs cannot keep the later ones
        (the master last) from closing; each failure is logged and none stops the others.
        """
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        clean = True
        while self._parts:
            name, part = self._parts.pop()
            budget = max((deadline - loop.time()) / (len(self._parts) + 1), 0.05)
            try:
                async with asyncio.timeout(budget):
                    await part.aclose()
            except TimeoutError:
                log.error("closing %s took longer than %.1f s; left behind", name, budget)
                clean = False
            except Exception as exc:
                log.error("closing %s failed: %s", name, reason(exc))
                clean = False
        if self._xmlrpc is not None:
            with contextlib.suppress(Exception):
                await self._xmlrpc.aclose()
            self._xmlrpc = None
        return clean

    def emergency_cleanup(self) -> None:
        """Remove what outlives the process (the IXM socket file) without the event loop; thread-safe."""
        if self.ixm is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.cfg.ixm.socket)


class SignalThread:
    """Receives SIGTERM, SIGINT and SIGHUP with ``sigwait`` on a thread of its own.

    asyncio's signal handlers run on the event loop, so a part that blocks the loop would also block the
    shutdown it asked for. This thread hands each signal to the loop and, from the first stop request on,
    enforces the hard deadline itself: past it, ``on_deadline`` runs here (and should exit the process).
    The signals must be blocked on the main thread before any other thread starts (``main()`` does it;
    ``start()`` blocks them too), so that every thread inherits the mask and only this one receives them.
    """

    SIGNALS = frozenset({signal.SIGTERM, signal.SIGINT, signal.SIGHUP})

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        on_stop: Callable[[], None],
        on_reload: Callable[[], None],
        deadline: float,
        on_deadline: Callable[[], None],
    ) -> None:
        self._loop = loop
        self._on_stop = on_stop
        self._on_reload = on_reload
        self._deadline = deadline
        self._on_deadline = on_deadline
        self._done = threading.Event()
        self._closing = False
        self._old_mask: set[int | signal.Signals] | None = None
        self._thread = threading.Thread(target=self._run, name="mrosd-signals", daemon=True)

    def start(self) -> None:
        self._old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, self.SIGNALS)
        self._thread.start()

    def _post(self, callback: Callable[[], None]) -> None:
        with contextlib.suppress(RuntimeError):  # the loop already closed
            self._loop.call_soon_threadsafe(callback)

    def _run(self) -> None:
        stopping = False
        while True:
            signum = signal.sigwait(self.SIGNALS)
            if self._closing:
                return
            if signum == signal.SIGHUP:
                self._post(self._on_reload)
            elif not stopping:
                stopping = True
                self._post(self._on_stop)
                if not self._done.wait(self._deadline) and not self._closing:
                    self._on_deadline()
                    return

    def close(self) -> None:
        """Stop the thread and restore the signal mask (``run()`` has finished its shutdown)."""
        self._closing = True
        self._done.set()
        if self._thread.ident is not None and self._thread.is_alive():
            with contextlib.suppress(OSError, ProcessLookupError):
                signal.pthread_kill(self._thread.ident, signal.SIGHUP)
            self._thread.join(1.0)
        if self._old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old_mask)
            self._old_mask = None


def _emergency_log(message: str) -> None:
    """Write one log line without taking logging's locks (the loop thread may hold them forever)."""
    record = logging.LogRecord("mrosd", logging.ERROR, __file__, 0, message, None, None)
    handlers = logging.getLogger().handlers
    text = handlers[0].format(record) if handlers else message
    with contextlib.suppress(OSError):
        os.write(2, (text + "\n").encode(errors="replace"))


async def _watchdog(daemon: Daemon, interval: float) -> None:
    while True:
        await asyncio.sleep(interval)
        if await daemon.master_alive(timeout=max(interval / 2, 0.1)):
            daemon.notifier.watchdog()
        else:
            log.warning("watchdog: the master did not answer getPid; not pinging systemd")


async def run(cfg: Config, *, config_path: str | None, master_only: bool, strict: bool = False) -> int:
    """Run until SIGTERM/SIGINT; returns the process exit code. Must run on the main thread."""
    loop = asyncio.get_running_loop()
    notifier = Notifier()
    daemon = Daemon(cfg, master_only=master_only, strict=strict, notifier=notifier)
    stop = asyncio.Event()
    reloads: asyncio.Queue[None] = asyncio.Queue(maxsize=1)  # a burst of SIGHUPs collapses into one reload

    def request_reload() -> None:
        with contextlib.suppress(asyncio.QueueFull):
            reloads.put_nowait(None)

    def hard_stop() -> None:
        _emergency_log(
            f"shutdown did not finish within {SHUTDOWN_TIMEOUT:.0f} s (a part blocks the event loop); "
            "removing the IXM socket and exiting"
        )
        daemon.emergency_cleanup()
        os._exit(EXIT_FAILURE)

    signals = SignalThread(loop, stop.set, request_reload, SHUTDOWN_TIMEOUT + HARD_STOP_GRACE, hard_stop)
    signals.start()
    tasks: list[asyncio.Task[None]] = []

    async def reloader() -> None:
        while True:
            await reloads.get()
            notifier.reloading()
            try:
                await daemon.reload(load_config(config_path))
            except Exception as exc:  # whatever the file holds, the running configuration stays
                log.error("SIGHUP: reload failed, keeping the running configuration: %s", reason(exc))
                if not isinstance(exc, MrosError):
                    log.debug("reload failure", exc_info=exc)
            notifier.ready(daemon.status_line())

    code = EXIT_OK
    try:
        try:
            await daemon.start()
        except (OSError, MrosError) as exc:
            log.error("cannot start: %s", reason(exc))
            notifier.status(f"failed: {reason(exc)}")
            code = EXIT_FAILURE
        else:
            notifier.ready(daemon.status_line())
            (log.warning if daemon.failed else log.info)("ready: %s", daemon.status_line())
            interval = watchdog_interval()
            if interval is not None:
                tasks.append(asyncio.create_task(_watchdog(daemon, interval), name="mrosd-watchdog"))
            tasks.append(asyncio.create_task(reloader(), name="mrosd-reloader"))
            await stop.wait()
            log.info("stopping")
    finally:
        notifier.stopping()
        for task in tasks:
            task.cancel()
        for result in await asyncio.gather(*tasks, return_exceptions=True):
            if isinstance(result, Exception):
                log.error("a daemon task failed: %s", reason(result))
        clean = await daemon.aclose(SHUTDOWN_TIMEOUT)
        signals.close()
        notifier.close()
    if not clean:
        log.error("stopped, but not every part closed within %.0f s", SHUTDOWN_TIMEOUT)
        return EXIT_FAILURE
    if code == EXIT_OK:
        log.info("stopped")
    return code


def build_parser() -> argparse.ArgumentParser:
    """The ``mrosd`` command line."""
    parser = argparse.ArgumentParser(
        prog="mrosd",
        description="mrosd: ROS 1 master + parameter server, IXM shared-memory registry and rosout aggregator.",
        epilog="Examples:\n  mrosd\n  mrosd --config /etc/mrosd/mrosd.toml --check-config\n  mrosd --master-only",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--config",
        "-c",
        metavar="FILE",
        help="TOML configuration (default: $MROSD_CONFIG, "
        "else /etc/mrosd/mrosd.toml when it exists, else built-in defaults)",
    )
    parser.add_argument("--check-config", action="store_true", help="validate the configuration, print it and exit")
    parser.add_argument(
        "--check",
        action="store_true",
        help="--check-config, then the descriptor budget of each part (derived from RLIMIT_NOFILE) and exit",
    )
    parser.add_argument("--master-only", action="store_true", help="run only the master and parameter server")
    parser.add_argument(
        "--strict",
        action="store_true",
        help="exit 1 when IXM, a bridge, rosout or web cannot start (default: run degraded)",
    )
    parser.add_argument("--port", "-p", type=int, help="master port (overrides the file and environment)")
    parser.add_argument("--log-level", choices=["debug", "info", "warning", "error"], help="log verbosity")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mrosd`` console script; returns (and exits with) the exit code."""
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(args.config)
        if cfg.ixm.enabled:  # validate [ixm.rules] now, not at the first client
            load_ixm_rules(cfg.ixm.rules, cfg.source)
            load_bridges(cfg.ixm.rules, cfg.source)
    except ConfigError as exc:
        print(f"mrosd: configuration error: {exc}", file=sys.stderr)
        return _exit(EXIT_USAGE, argv)
    if args.port is not None:
        if not 0 <= args.port <= 65535:
            print(f"mrosd: --port must be 0..65535, got {args.port}", file=sys.stderr)
            return _exit(EXIT_USAGE, argv)
        cfg.master.port = args.port
    if args.log_level:
        cfg.log.level = args.log_level
    if args.check_config or args.check:
        import msgspec

        print(f"configuration OK ({cfg.source or 'built-in defaults'})")
        print(msgspec.json.format(msgspec.json.encode(cfg), indent=2).decode())
        if args.check:
            print("\n".join(planned_budgets().lines()))
        return _exit(EXIT_OK, argv)
    setup_logging(cfg.log.level)
    raise_nofile_limit()  # before any part sizes its caps from it
    # Blocked before any thread exists, so that every thread inherits the mask and only SignalThread gets them.
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, SignalThread.SIGNALS)
    try:
        with asyncio.Runner(loop_factory=event_loop_factory()) as runner:
            code = runner.run(run(cfg, config_path=args.config, master_only=args.master_only, strict=args.strict))
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    return _exit(code, argv)


def _exit(code: int, argv: Sequence[str] | None) -> int:
    # As a console script (argv None) exit with the code; called from Python, just return it.
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
