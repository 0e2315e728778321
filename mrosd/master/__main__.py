"""``python -m mrosd.master``: run the master alone (also used by ``mrosd --master-only``).

The default port comes from ROS_MASTER_URI (11311 if unset); the advertised URI from
ROS_HOSTNAME/ROS_IP. Stops cleanly on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys

from mrosd.loop import run
from mrosd.master.cleanup import DEFAULT_CLEANUP_INTERVAL
from mrosd.master.server import Master, parse_networks, port_from_master_uri


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m mrosd.master", description="Run the mrosd ROS 1 master.")
    parser.add_argument("--host", default="0.0.0.0", help="address to bind (default 0.0.0.0)")
    parser.add_argument(
        "--port", "-p", type=int, default=None, help="TCP port (default: ROS_MASTER_URI's port, else 11311)"
    )
    parser.add_argument(
        "--allow",
        action="append",
        default=None,
        metavar="NET",
        help="client network allowed to call, e.g. 127.0.0.0/8 (repeatable; default: everyone)",
    )
    parser.add_argument(
        "--cleanup-interval",
        type=float,
        default=DEFAULT_CLEANUP_INTERVAL,
        metavar="SECONDS",
        help=f"remove nodes whose slave API refuses connections this often (default {DEFAULT_CLEANUP_INTERVAL:g}; "
        "0 = never, as rosmaster)",
    )
    parser.add_argument("--no-uvloop", action="store_true", help="use the stock asyncio loop (as MROSD_LOOP=asyncio)")
    parser.add_argument("-v", "--verbose", action="store_true", help="log failed notifications (rate-limited)")
    return parser.parse_args(argv)


async def serve(args: argparse.Namespace) -> None:
    """Run a master until SIGINT/SIGTERM."""
    port = args.port if args.port is not None else port_from_master_uri(os.environ.get("ROS_MASTER_URI"))
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    async with Master(args.host, port, allow=args.allow, cleanup_interval=args.cleanup_interval) as master:
        print(f"mrosd master ready at {master.uri}", flush=True)
        await stop.wait()


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.allow is not None:
        try:
            parse_networks(args.allow)
        except ValueError as exc:
            print(f"mrosd master: bad --allow network: {exc}", file=sys.stderr)
            return 2
    if args.cleanup_interval < 0:
        print("mrosd master: --cleanup-interval must be >= 0 (0 turns the sweep off)", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(asctime)s %(name)s: %(message)s"
    )
    try:
        run(serve(args), use_uvloop=not args.no_uvloop)
    except OSError as exc:
        print(f"mrosd master: cannot listen: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
