"""``python -m mrosd.ixm --socket PATH [--config TOML]``: run the IXM registry alone (no master).

The ``mrosd`` daemon composes the same ``IxmServer`` with the master; this entry point exists for tests,
benchmarks and machines that want shared memory without ROS. SIGHUP reloads the access rules from the
file; SIGTERM/SIGINT free every segment and exit 0. Prints ``ready`` on stdout once the socket listens.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import resource
import signal
import sys
from typing import Any

from mrosd.backports import tomllib
from mrosd.errors import ConfigError, MrosError
from mrosd.ixm.rules import AccessRules, parse_rules
from mrosd.ixm.server import IxmServer


def load_rules_file(path: str | None) -> AccessRules:
    """The ``[ixm.rules]`` table of a daemon config file (same format as ``mrosd --config``).

    Raises:
        ConfigError: the file is unreadable, not TOML, or its rules are invalid.
    """
    if path is None:
        return AccessRules()
    try:
        with open(path, "rb") as f:
            raw: dict[str, Any] = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    ixm = raw.get("ixm", {})
    rules = ixm.get("rules", {}) if isinstance(ixm, dict) else {}
    return parse_rules(rules, f"{path}: ixm.rules")


def raise_fd_limit() -> None:
    """Lift the soft descriptor limit to the hard one: the caps are a share of it (``Limits``)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


async def serve(socket_path: str, config: str | None, limits: dict[str, int | None] | None = None) -> int:
    raise_fd_limit()
    server = IxmServer(socket_path, load_rules_file(config), **(limits or {}))
    await server.start()
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)

    def reload() -> None:
        try:
            server.reload_rules(load_rules_file(config))
        except MrosError as exc:
            logging.getLogger("mrosd.ixm").error("rules not reloaded: %s", exc)

    loop.add_signal_handler(signal.SIGHUP, reload)
    print("ready", flush=True)
    try:
        await stop.wait()
    finally:
        await server.aclose()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mrosd.ixm", description=__doc__.splitlines()[0])
    parser.add_argument("--socket", required=True, help="Unix socket path to listen on")
    parser.add_argument("--config", help="TOML file whose [ixm.rules] table holds the access rules")
    parser.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])
    caps = ("max_clients", "max_clients_per_uid", "max_keys", "max_keys_per_uid")
    for cap in caps:
        parser.add_argument(
            "--" + cap.replace("_", "-"), type=int, default=None, help="cap (default: a share of the fd limit)"
        )
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return asyncio.run(serve(args.socket, args.config, {cap: getattr(args, cap) for cap in caps}))
    except MrosError as exc:
        print(f"mrosd.ixm: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, ConfigError) else 1


if __name__ == "__main__":
    sys.exit(main())
