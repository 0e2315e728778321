"""``mrosd``: the service users run. One event loop holding the master, the IXM registry and rosout.

This module owns the process: command line, configuration loading, logging format, the event loop (uvloop
when installed), POSIX signals and the systemd protocol. The parts it composes (``mrosd.master.Master``,
``mrosd.ixm.server.IxmServer``, ``mrosd.rosout.RosoutAggregator``) are embeddable servers with
``start()``/``aclose()`` and know nothing of signals or systemd.

Lifecycle, as systemd sees it (``Type=notify``):
  1. start the master, then check it answers ``getPid`` over XML-RPC, then start IXM and rosout;
  2. send ``READY=1`` with a status line; ping ``WATCHDOG=1`` at half ``WATCHDOG_USEC`` while the master
     still answers its own ``getPid``;
  3. ``SIGHUP`` re-reads the file and reloads the IXM access rules (other sections need a restart);
  4. ``SIGTERM``/``SIGINT`` send ``STOPPING=1`` and close every part within ``SHUTDOWN_TIMEOUT`` seconds
     (sockets closed, shared-memory segments unlinked by the IXM server), then exit 0.

Exit codes: 0 clean stop, 1 runtime failure (a port in use, a part failed to start), 2 bad configuration
or usage.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib
import inspect
import logging
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mrosd.config import Config, load_config
from mrosd.errors import ConfigError, MrosError
from mrosd.sdnotify import Notifier, watchdog_interval

log = logging.getLogger("mrosd")

#: Upper bound on a clean shutdown; systemd's TimeoutStopSec in the unit is larger (10 s) so that we, not
#: SIGKILL, decide what is left behind.
SHUTDOWN_TIMEOUT = 5.0

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


def local_master_uri(cfg: Config, port: int) -> str:
    """The URI this process uses to reach its own master (loopback when it listens on every address)."""
    host = cfg.master.host
    if host in ("", "0.0.0.0", "::"):
        host = "127.0.0.1" if host != "::" else "::1"
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}/"


def _import_attr(module: str, name: str) -> Any:
    """Import a part lazily (so that ``--check-config`` stays fast); ImportError when the part is missing."""
    try:
        return getattr(importlib.import_module(module), name)
    except AttributeError as exc:
        raise ImportError(f"{module}.{name} is missing") from exc


def _load_ixm_rules(raw: dict[str, Any], source: str = "") -> Any:
    """Parse the opaque ``[ixm.rules]`` table with the IXM part's parser (ConfigError naming the key)."""
    try:
        rules_mod = importlib.import_module("mrosd.ixm.rules")
    except ImportError:
        return raw
    where = f"{source}: ixm.rules" if source else "ixm.rules"
    return rules_mod.parse_rules(raw, where)


class Daemon:
    """The composed parts and their lifecycle; ``main()`` owns the loop and the signals."""

    def __init__(self, cfg: Config, *, master_only: bool = False, notifier: Notifier | None = None) -> None:
        self.cfg = cfg
        self.master_only = master_only
        self.notifier = notifier if notifier is not None else Notifier()
        self.master: Any = None
        self.ixm: Any = None
        self.rosout: Any = None
        self.master_uri = ""
        self._parts: list[tuple[str, Any]] = []
        self._xmlrpc: Any = None

    async def start(self) -> None:
        """Start every configured part; on failure the parts already started are closed again.

        Raises:
            OSError: a socket could not be bound (port in use, permission).
            MrosError: a part refused to start.
        """
        try:
            await self._start_master()
            await self._wait_master_answers()
            if not self.master_only and self.cfg.ixm.enabled:
                await self._start_ixm()
            if not self.master_only and self.cfg.rosout.enabled:
                await self._start_rosout()
        except BaseException:
            await self.aclose()
            raise

    async def _start_master(self) -> None:
        Master = _import_attr("mrosd.master", "Master")

        kwargs: dict[str, Any] = {"host": self.cfg.master.host, "port": self.cfg.master.port}
        if self.cfg.master.allow:
            if "allow" in inspect.signature(Master).parameters:
                kwargs["allow"] = list(self.cfg.master.allow)
            else:
                log.warning("master.allow is set but this master does not support network filtering; ignored")
        master = Master(**kwargs)
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
        try:
            IxmServer = _import_attr("mrosd.ixm.server", "IxmServer")
        except ImportError as exc:
            log.warning("IXM registry unavailable in this build (%s); continuing without it", exc)
            return
        path = Path(self.cfg.ixm.socket)
        path.parent.mkdir(parents=True, exist_ok=True)
        server = IxmServer(str(path), _load_ixm_rules(self.cfg.ixm.rules, self.cfg.source))
        await server.start()
        self.ixm = server
        self._parts.append(("ixm", server))
        log.info("IXM registry listening on %s", path)

    async def _start_rosout(self) -> None:
        try:
            RosoutAggregator = _import_attr("mrosd.rosout", "RosoutAggregator")
        except ImportError as exc:
            log.warning("rosout aggregator unavailable in this build (%s); continuing without it", exc)
            return
        agg = RosoutAggregator(self.master_uri)
        try:
            await agg.start()
        except (ImportError, MrosError, OSError) as exc:
            # The master is what clients need first; a missing /rosout_agg is worth a warning, not an outage.
            log.warning("rosout aggregator did not start (%s); continuing without it", exc)
            return
        self.rosout = agg
        self._parts.append(("rosout", agg))
        log.info("rosout aggregator running (/rosout -> /rosout_agg)")

    def status_line(self) -> str:
        """The one-line status for ``systemctl status``."""
        parts = [f"master {self.master_uri}"]
        if self.ixm is not None:
            parts.append(f"ixm {self.cfg.ixm.socket}")
        if self.rosout is not None:
            parts.append("rosout")
        return "running: " + ", ".join(parts)

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
        """Apply a re-read configuration: IXM access rules now; other changes are logged as needing a restart."""
        if (cfg.master, cfg.rosout) != (self.cfg.master, self.cfg.rosout) or cfg.ixm.socket != self.cfg.ixm.socket:
            log.warning("SIGHUP: only [ixm.rules] is reloaded; restart mrosd to apply the other changes")
        if self.ixm is not None:
            result = self.ixm.reload_rules(_load_ixm_rules(cfg.ixm.rules, cfg.source))
            if inspect.isawaitable(result):
                await result
            log.info("SIGHUP: IXM access rules reloaded from %s", cfg.source or "defaults")
        self.cfg.ixm.rules = cfg.ixm.rules

    async def aclose(self) -> None:
        """Close the parts in reverse start order; each failure is logged, none stops the others."""
        while self._parts:
            name, part = self._parts.pop()
            try:
                await part.aclose()
            except Exception:
                log.exception("closing %s failed", name)
        if self._xmlrpc is not None:
            with contextlib.suppress(Exception):
                await self._xmlrpc.aclose()
            self._xmlrpc = None


async def _watchdog(daemon: Daemon, interval: float) -> None:
    while True:
        await asyncio.sleep(interval)
        if await daemon.master_alive(timeout=max(interval / 2, 0.1)):
            daemon.notifier.watchdog()
        else:
            log.warning("watchdog: the master did not answer getPid; not pinging systemd")


async def run(cfg: Config, *, config_path: str | None, master_only: bool) -> int:
    """Run until SIGTERM/SIGINT; returns the process exit code."""
    loop = asyncio.get_running_loop()
    notifier = Notifier()
    daemon = Daemon(cfg, master_only=master_only, notifier=notifier)
    stop = asyncio.Event()
    reloads: asyncio.Queue[None] = asyncio.Queue(maxsize=1)  # a burst of SIGHUPs collapses into one reload

    def request_reload() -> None:
        with contextlib.suppress(asyncio.QueueFull):
            reloads.put_nowait(None)

    handlers: dict[signal.Signals, Callable[[], None]] = {
        signal.SIGTERM: stop.set,
        signal.SIGINT: stop.set,
        signal.SIGHUP: request_reload,
    }
    for signum, handler in handlers.items():
        loop.add_signal_handler(signum, handler)
    try:
        try:
            await daemon.start()
        except OSError as exc:
            log.error("cannot start: %s", exc)
            notifier.status(f"failed: {exc}")
            return EXIT_FAILURE
        except MrosError as exc:
            log.error("cannot start: %s", exc)
            notifier.status(f"failed: {exc}")
            return EXIT_FAILURE
        notifier.ready(daemon.status_line())
        log.info("ready: %s", daemon.status_line())
        tasks: list[asyncio.Task[None]] = []
        interval = watchdog_interval()
        if interval is not None:
            tasks.append(asyncio.create_task(_watchdog(daemon, interval), name="mrosd-watchdog"))

        async def reloader() -> None:
            while True:
                await reloads.get()
                notifier.reloading()
                try:
                    new_cfg = load_config(config_path)
                    await daemon.reload(new_cfg)
                except (MrosError, OSError, ValueError) as exc:
                    log.error("SIGHUP: reload failed, keeping the running configuration: %s", exc)
                notifier.ready(daemon.status_line())

        tasks.append(asyncio.create_task(reloader(), name="mrosd-reloader"))
        await stop.wait()
        log.info("stopping")
        notifier.stopping()
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        try:
            async with asyncio.timeout(SHUTDOWN_TIMEOUT):
                await daemon.aclose()
        except TimeoutError:
            log.error("shutdown took longer than %.0f s; exiting anyway", SHUTDOWN_TIMEOUT)
            return EXIT_FAILURE
        log.info("stopped")
        return EXIT_OK
    finally:
        for signum in handlers:
            loop.remove_signal_handler(signum)
        notifier.close()


def build_parser() -> argparse.ArgumentParser:
    """The ``mrosd`` command line."""
    parser = argparse.ArgumentParser(
        prog="mrosd",
        description="mrosd: ROS 1 master + parameter server, IXM shared-memory registry and rosout aggregator.",
        epilog="Examples:\n  mrosd\n  mrosd --config /etc/mrosd/mrosd.toml --check-config\n  mrosd --master-only",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", "-c", metavar="FILE", help="TOML configuration (default: $MROSD_CONFIG, "
                        "else /etc/mrosd/mrosd.toml when it exists, else built-in defaults)")
    parser.add_argument("--check-config", action="store_true", help="validate the configuration, print it and exit")
    parser.add_argument("--master-only", action="store_true", help="run only the master and parameter server")
    parser.add_argument("--port", "-p", type=int, help="master port (overrides the file and environment)")
    parser.add_argument("--log-level", choices=["debug", "info", "warning", "error"], help="log verbosity")
    return parser


def _new_loop_factory() -> Callable[[], asyncio.AbstractEventLoop] | None:
    # MROSD_LOOP=asyncio selects the standard loop (for debugging, or to rule uvloop out).
    if os.environ.get("MROSD_LOOP", "uvloop") == "asyncio":
        return None
    try:
        import uvloop
    except ImportError:
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mrosd`` console script; returns (and exits with) the exit code."""
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(args.config)
        if cfg.ixm.enabled:
            _load_ixm_rules(cfg.ixm.rules, cfg.source)  # validate [ixm.rules] now, not at the first client
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
    if args.check_config:
        import msgspec

        print(f"configuration OK ({cfg.source or 'built-in defaults'})")
        print(msgspec.json.format(msgspec.json.encode(cfg), indent=2).decode())
        return _exit(EXIT_OK, argv)
    setup_logging(cfg.log.level)
    with asyncio.Runner(loop_factory=_new_loop_factory()) as runner:
        code = runner.run(run(cfg, config_path=args.config, master_only=args.master_only))
    return _exit(code, argv)


def _exit(code: int, argv: Sequence[str] | None) -> int:
    # As a console script (argv None) exit with the code; called from Python, just return it.
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
