"""``Daemon``: the parts the ``mrosd`` process composes, and their lifecycle.

Starts the master (the one part whose failure is fatal), then IXM, its topic bridges, rosout, web and fleet,
each of which may fail alone (degraded mode); starts again on SIGHUP those that failed; applies a re-read
configuration; says what runs (``status_line``, the status file); closes them in reverse order within a
deadline. It knows nothing of signals, the command line or systemd's socket (``mrosd.daemon`` owns those).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import resource
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.config import Config, FleetConfig, LogConfig, part_options
from mrosd.errors import MrosError
from mrosd.fdbudget import FdBudgets, fd_budgets
from mrosd.process import reason
from mrosd.sdnotify import Notifier

if TYPE_CHECKING:
    from mrosd.fleet.bridge import FleetBridge
    from mrosd.ixm.bridge import Bridge, IxmBridge
    from mrosd.ixm.rules import AccessRules
    from mrosd.ixm.server import IxmServer
    from mrosd.logfiles import RunLogs
    from mrosd.master import Master
    from mrosd.rosout import RosoutAggregator
    from mrosd.runstatus import DaemonStatus
    from mrosd.tcpros.admission import AdmissionLimits
    from mrosd.web.server import WebServer
    from mrosd.xmlrpc import XmlRpcClient

__all__ = ["READY_TIMEOUT", "SHUTDOWN_TIMEOUT", "Daemon", "load_bridges", "load_ixm_rules", "local_master_uri"]

log = logging.getLogger("mrosd")

#: Upper bound on a clean shutdown; systemd's TimeoutStopSec in the unit is larger (10 s) so that we, not
#: SIGKILL, decide what is left behind.
SHUTDOWN_TIMEOUT = 5.0

#: How long the start-up self-check waits for the master to answer its first getPid.
READY_TIMEOUT = 10.0


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
        self._status_file: str | None = None

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
            if not self.master_only and self.cfg.images.compressed:
                await self._optional("images", self._start_images)
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

        self.run_id = self.run_id or new_run_id()  # a reload moves this run's files; the id stays
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
        self._parts.insert(0, ("logs", logs))  # first in, last out: master.log sees the whole shutdown
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
        host, port = self.cfg.master.host, self.cfg.master.port
        master = Master(host, port, allow=allow, **options)
        try:
            await master.start()
        except OSError as exc:  # name the port: "Address already in use" alone does not say which
            raise OSError(exc.errno, f"{exc.strerror or exc}: master port {port} on {host or '*'}") from exc
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
        from mrosd.web.compressed import rules_from_config
        from mrosd.web.foxglove_server import SessionLimits
        from mrosd.web.server import WebServer

        web = self.cfg.web
        policy = AccessPolicy(
            topics=web.topics,
            services=web.services,
            params=web.params,
            assets=web.assets,
            token=web.token,
            hostnames=web.hostnames,
            allowed_origins=web.allowed_origins,
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
        server.hub.compressed.rules = rules_from_config(web.images)
        if self.master is not None:  # the hub follows the graph from the master's own change notes
            server.hub.use_master(self.master)
        if web.max_clients is not None:
            server.max_clients = web.max_clients
        if self.budgets is not None:  # half the web budget for clients' sockets, half for the hub's TCPROS links
            server.max_clients = max(1, min(server.max_clients, self.budgets.web // 2))
        await server.start()
        server.on_drops = self.publish_status  # what slow clients lose shows in `mros daemon status`
        self.web = server
        self._parts.append(("web", server))
        if web.tf_republisher:  # roslibjs's and roslibpy's TFClient, with no tf2_web_republisher node
            server.first_client_hooks.append(self._start_tf_republisher)  # joins the graph with the first client

    async def _start_tf_republisher(self) -> None:
        from mrosd.tf.republish_node import TFRepublisherNode

        if any(name == "tf2_web_republisher" for name, _ in self._parts):
            return  # started for an earlier web part's first client
        try:
            tf = TFRepublisherNode(self.master_uri, admission=self._tcpros_admission())
            self._parts.append(("tf2_web_republisher", await tf.start()))
        except (MrosError, OSError) as exc:
            log.error("tf2_web_republisher did not start: %s; the web part runs without it", reason(exc))

    async def _start_fleet(self) -> None:
        from mrosd.fleet.bridge import FleetBridge
        from mrosd.fleet.options import fleet_options

        options = fleet_options(self.cfg.fleet, self.cfg.source or "configuration")
        budget = self.budgets.fleet if self.budgets is not None else None
        fleet = FleetBridge(options, self.master_uri, fd_budget=budget)
        await fleet.start()
        self.fleet = fleet
        self._parts.append(("fleet", fleet))
        log.info("fleet: robot %s linked over Zenoh", self.cfg.fleet.robot)

    async def _start_images(self) -> None:
        from mrosd.images.encoding import EncodeSettings
        from mrosd.images.part import CompressedImages

        cfg = self.cfg.images
        settings = EncodeSettings(quality=cfg.quality, max_width=cfg.max_width, png_level=cfg.png_level)
        part = CompressedImages(self.master_uri, cfg.compressed, settings, admission=self._tcpros_admission())
        await part.start()
        self._parts.append(("images", part))

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
        parts += [part.summary() for name, part in self._parts if name == "ros2"]
        line = ", ".join(parts)
        if not self.failed:
            return "running: " + line
        return "degraded: " + line + "; " + "; ".join(f"{name} failed: {why}" for name, why in self.failed.items())

    def status(self) -> DaemonStatus:
        """What runs and where, for the status file (``mrosd.runstatus``)."""
        import mrosd
        from mrosd.runstatus import ClientDrops, DaemonStatus, EncoderCounts, WebStatus

        web = None
        if self.web is not None:
            web = WebStatus(
                page=self.web.page_url.split("?", 1)[0],
                foxglove=list(self.web.urls),
                rosbridge=list(self.web.rosbridge_urls) if self.web.rosbridge_port is not None else [],
                token_required=bool(self.web.policy.token),
                drops=[ClientDrops(client=c, dropped=d) for c, d in self.web.drops()],
                encoders=[
                    EncoderCounts(
                        topic=t,
                        encoded=c["encoded"],
                        dropped=c["dropped"],
                        refused=c["refused"],
                        encode_ms=c["encodeMs"],
                    )
                    for t, c in self.web.encoders()
                ],
            )
        return DaemonStatus(
            pid=os.getpid(),
            version=mrosd.__version__,
            master_uri=self.master_uri,
            state="degraded" if self.failed else "running",
            ixm=self.cfg.ixm.socket if self.ixm is not None else None,
            ixm_bridges=len(self.bridge.bridges) if self.bridge is not None else 0,
            rosout=self.rosout is not None,
            web=web,
            fleet=self.cfg.fleet.robot if self.fleet is not None else None,
            failed=dict(self.failed),
        )

    def publish_status(self) -> None:
        """Write the status file into the runtime directory (the IXM socket's), creating it as IXM would;
        a failure is one warning (``mros web`` then falls back to the configuration)."""
        if self.master is None:
            return
        from mrosd.ixm.rundir import prepare_socket_dir
        from mrosd.runstatus import status_path, write_status

        run_dir = os.path.dirname(os.path.abspath(self.cfg.ixm.socket))
        path = status_path(run_dir, int(self.master.port))
        try:
            prepare_socket_dir(run_dir)
            write_status(path, self.status())
        except (OSError, MrosError) as exc:
            log.warning("no status file %s: %s", path, reason(exc))
            return
        self._status_file = path

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
        """Apply a re-read configuration: IXM access rules now, ``[log]`` and ``[fleet]`` by restarting their
        parts, and the parts that failed to start are tried again; other changes are logged as needing a
        restart.

        Raises:
            ConfigError: the new rules or fleet settings do not parse (everything running stays).
        """
        rules = load_ixm_rules(cfg.ixm.rules, cfg.source)
        old = self.cfg
        if cfg.fleet != old.fleet and cfg.fleet.enabled:
            from mrosd.fleet.options import fleet_options

            fleet_options(cfg.fleet, cfg.source or "configuration")  # refuse a bad [fleet] before stopping ours
        if (cfg.master, cfg.rosout, cfg.web) != (old.master, old.rosout, old.web) or cfg.ixm.socket != old.ixm.socket:
            log.warning("SIGHUP: [master], [rosout], [web] and ixm.socket are applied at the next restart of mrosd")
        if cfg.ixm.rules.get("bridges") != old.ixm.rules.get("bridges"):
            log.warning("SIGHUP: [ixm.rules.bridges] changed; restart mrosd to apply it")
        if self.ixm is not None:
            self.ixm.reload_rules(rules)
            log.info("SIGHUP: IXM access rules reloaded from %s", cfg.source or "defaults")
        self.cfg.ixm.rules = cfg.ixm.rules
        if cfg.log != old.log:
            await self._apply_log(cfg.log)
        if cfg.fleet != old.fleet:
            await self._restart_fleet(cfg.fleet)
        if self.failed:
            await self._retry_failed()

    async def _apply_log(self, new: LogConfig) -> None:
        """``[log]``: the level at once; a new directory or rotation by reopening this run's files there
        (master.log, then rosout.log through a restarted rosout aggregator)."""
        old, self.cfg.log = self.cfg.log, new
        if new.level != old.level:
            logging.getLogger().setLevel(new.level.upper())
        if (new.dir, new.max_bytes, new.backups) != (old.dir, old.max_bytes, old.backups):
            await self._close_part("logs")
            self.logs = None
            self._open_logs()
            if self.logs is not None and self.master is not None:
                self.logs.follow_graph(self.master.api)
            if self.rosout is not None:
                await self._close_part("rosout")
                self.rosout = None
                await self._optional("rosout", self._start_rosout)
        where = self.logs.dir if self.logs is not None else "no log files"
        log.info("SIGHUP: [log] applied (level %s, %s)", new.level, where)

    async def _restart_fleet(self, new: FleetConfig) -> None:
        """``[fleet]``: the fleet part stops and, when still enabled, starts again with the new settings."""
        self.cfg.fleet = new
        self.failed.pop("fleet", None)
        if self.fleet is not None:
            await self._close_part("fleet")
            self.fleet = None
        if new.enabled and not self.master_only:
            await self._optional("fleet", self._start_fleet)
        log.info("SIGHUP: [fleet] applied (%s)", "running" if self.fleet is not None else "off")

    async def _close_part(self, name: str) -> None:
        """Close one running part (a reload restarts it), bounded like a shutdown; failures are logged."""
        for i, (part_name, part) in enumerate(self._parts):
            if part_name != name:
                continue
            del self._parts[i]
            try:
                async with backports.timeout(SHUTDOWN_TIMEOUT):
                    await part.aclose()
            except TimeoutError:
                log.error("closing %s took longer than %.1f s; left behind", name, SHUTDOWN_TIMEOUT)
            except Exception as exc:
                log.error("closing %s failed: %s", name, reason(exc))
            return

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
        if "images" in retry:
            await self._optional("images", self._start_images)
        if "ros2" in retry:
            await self._optional("ros2", self._start_ros2)

    async def aclose(self, timeout: float = SHUTDOWN_TIMEOUT) -> bool:
        """Close the parts in reverse start order within ``timeout`` seconds in all; True when all closed.

        Each part gets a fair share of the time left, so one part that hangs cannot keep the later ones
        (the master last) from closing; each failure is logged and none stops the others.
        """
        if self._status_file is not None:  # first: a client must not find a daemon that is going away
            from mrosd.runstatus import remove_status

            remove_status(self._status_file)
            self._status_file = None
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        clean = True
        while self._parts:
            name, part = self._parts.pop()
            budget = max((deadline - loop.time()) / (len(self._parts) + 1), 0.05)
            try:
                async with backports.timeout(budget):
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
