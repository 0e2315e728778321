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
import signal
import sys
from collections.abc import Callable, Sequence

from mrosd import backports
from mrosd.config import Config, load_config
from mrosd.errors import ConfigError, MrosError
from mrosd.loop import event_loop_factory
from mrosd.parts import SHUTDOWN_TIMEOUT, Daemon, load_bridges, load_ixm_rules
from mrosd.process import planned_budgets, raise_nofile_limit, reason, setup_logging
from mrosd.sdnotify import Notifier, watchdog_interval
from mrosd.signals import SignalThread, emergency_log

__all__ = ["EXIT_FAILURE", "EXIT_OK", "EXIT_USAGE", "HARD_STOP_GRACE", "SHUTDOWN_TIMEOUT", "Daemon", "main", "run"]

log = logging.getLogger("mrosd")

#: After SHUTDOWN_TIMEOUT plus this, a shutdown that is still not done (a part blocks the event loop) is
#: cut short from the signal thread: the IXM socket is unlinked and the process exits 1.
HARD_STOP_GRACE = 1.0

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


async def _watchdog(daemon: Daemon, interval: float) -> None:
    while True:
        await asyncio.sleep(interval)
        if await daemon.master_alive(timeout=max(interval / 2, 0.1)):
            daemon.notifier.watchdog()
        else:
            log.warning("watchdog: the master did not answer getPid; not pinging systemd")


async def run(
    cfg: Config,
    *,
    config_path: str | None,
    master_only: bool,
    strict: bool = False,
    reread: Callable[[], Config] | None = None,
) -> int:
    """Run until SIGTERM/SIGINT; returns the process exit code. Must run on the main thread.

    ``reread`` gives the configuration a SIGHUP applies (default: ``config_path`` read again).
    """
    loop = asyncio.get_running_loop()
    notifier = Notifier()
    daemon = Daemon(cfg, master_only=master_only, strict=strict, notifier=notifier)
    stop = asyncio.Event()
    reloads: asyncio.Queue[None] = asyncio.Queue(maxsize=1)  # a burst of SIGHUPs collapses into one reload

    def request_reload() -> None:
        with contextlib.suppress(asyncio.QueueFull):
            reloads.put_nowait(None)

    def hard_stop() -> None:
        emergency_log(
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
                await daemon.reload(reread() if reread is not None else load_config(config_path))
            except Exception as exc:  # whatever the file holds, the running configuration stays
                log.error("SIGHUP: reload failed, keeping the running configuration: %s", reason(exc))
                if not isinstance(exc, MrosError):
                    log.debug("reload failure", exc_info=exc)
            daemon.publish_status()
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
            daemon.publish_status()
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


#: The end of ``mrosd --help``: examples, and the variables that set what the flags do not.
EPILOG = """\
Examples:
  mrosd
  mrosd --config /etc/mrosd/mrosd.toml --check-config
  mrosd --master-only
  mrosd --web-port 8765 --rosbridge-port 9090     # then: mros web

Environment (each overrides its key in the file; a flag overrides its variable):
  MROSD_CONFIG              the configuration file
  ROS_MASTER_URI            its port is the master's; MROSD_MASTER_HOST, MROSD_MASTER_PORT, MROSD_MASTER_ALLOW
  MROSD_IXM, MROSD_IXM_SOCKET, MROSD_ROSOUT   the IXM registry (1/0, its socket) and rosout (1/0)
  MROSD_WEB                 the web part (1/0)
  MROSD_WEB_PORT            the page and Foxglove WebSocket port (default 8765)
  MROSD_WEB_ROSBRIDGE_PORT  rosbridge v2 (default 9090; -1: off)
  MROSD_WEB_HOST            bind address(es), comma-separated (default 127.0.0.1)
  MROSD_WEB_TOKEN           the token clients must present (required off loopback)
  MROSD_LOG_LEVEL           debug, info, warning or error
  MROSD_LOOP=asyncio        asyncio's own event loop instead of uvloop
"""


def build_parser() -> argparse.ArgumentParser:
    """The ``mrosd`` command line."""
    import mrosd

    parser = argparse.ArgumentParser(
        prog="mrosd",
        description="mrosd: ROS 1 master + parameter server, IXM shared-memory registry, rosout aggregator, "
        "and the web part: a page (graph, topics, plots, images) and Foxglove WebSocket on one port, rosbridge "
        "v2 on another.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"mrosd {mrosd.__version__}")
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
    web = parser.add_argument_group("web part ([web] in the file; each flag overrides its variable)")
    web.add_argument(
        "--web-port", type=int, metavar="PORT", help="the page and Foxglove WebSocket port ($MROSD_WEB_PORT)"
    )
    web.add_argument(
        "--rosbridge-port", type=int, metavar="PORT", help="rosbridge v2 port, -1: off ($MROSD_WEB_ROSBRIDGE_PORT)"
    )
    web.add_argument(
        "--web-host",
        metavar="ADDR[,ADDR]",
        help="bind address(es); one that is not loopback needs $MROSD_WEB_TOKEN ($MROSD_WEB_HOST)",
    )
    web.add_argument("--no-web", action="store_true", help="run without the web part ($MROSD_WEB=0)")
    parser.add_argument("--log-level", choices=["debug", "info", "warning", "error"], help="log verbosity")
    return parser


def _flag_environment(args: argparse.Namespace) -> dict[str, str] | None:
    """The web flags as the ``MROSD_WEB_*`` overrides they stand for (a flag wins over its variable)."""
    flags = {
        "MROSD_WEB_PORT": args.web_port,
        "MROSD_WEB_ROSBRIDGE_PORT": args.rosbridge_port,
        "MROSD_WEB_HOST": args.web_host,
        "MROSD_WEB": "0" if args.no_web else None,
    }
    given = {k: str(v) for k, v in flags.items() if v is not None}
    return {**os.environ, **given} if given else None


def _load(args: argparse.Namespace) -> Config:
    """The configuration with the command line's overrides on top (at start and at each SIGHUP).

    Raises:
        ConfigError: as ``load_config``.
    """
    cfg = load_config(args.config, _flag_environment(args))
    if args.port is not None:
        cfg.master.port = args.port
    if args.log_level:
        cfg.log.level = args.log_level
    return cfg


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mrosd`` console script; returns (and exits with) the exit code."""
    args = build_parser().parse_args(argv)
    for flag, value, low in (("--web-port", args.web_port, 0), ("--rosbridge-port", args.rosbridge_port, -1)):
        if value is not None and not low <= value <= 65535:
            print(f"mrosd: {flag} must be {low}..65535, got {value}", file=sys.stderr)
            return _exit(EXIT_USAGE, argv)
    if args.port is not None and not 0 <= args.port <= 65535:
        print(f"mrosd: --port must be 0..65535, got {args.port}", file=sys.stderr)
        return _exit(EXIT_USAGE, argv)
    try:
        cfg = _load(args)
        if cfg.ixm.enabled:  # validate [ixm.rules] now, not at the first client
            load_ixm_rules(cfg.ixm.rules, cfg.source)
            load_bridges(cfg.ixm.rules, cfg.source)
    except ConfigError as exc:
        print(f"mrosd: configuration error: {exc}", file=sys.stderr)
        return _exit(EXIT_USAGE, argv)
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
        with backports.Runner(loop_factory=event_loop_factory()) as runner:
            daemon = run(
                cfg,
                config_path=args.config,
                master_only=args.master_only,
                strict=args.strict,
                reread=lambda: _load(args),
            )
            code = runner.run(daemon)
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
