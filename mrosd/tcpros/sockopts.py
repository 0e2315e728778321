"""Socket options every TCPROS connection gets, in one place.

Buffer sizes are left to the kernel's autotuning on purpose: it grows a busy connection's buffers to
``tcp_wmem``/``tcp_rmem``'s maximum (4 MB / 32 MB on Debian), which already fits megabyte frames, while a
fixed ``SO_SNDBUF``/``SO_RCVBUF`` turns autotuning off and is capped lower (``wmem_max``). A 4 MB
``SO_SNDBUF`` was measured (bench.tcpros, images) and gained nothing, and it let a stalled subscriber park
8 MB of stale frames in the kernel before the drop-oldest queue saw any back-pressure.

Keepalive follows rospy (idle 60 s, interval 10 s, 9 probes): a peer whose host vanishes without a FIN or
RST (power loss, a cable pulled, a network namespace deleted) is detected in about 2.5 minutes instead of
never, and the connection's resources are released.
"""

from __future__ import annotations

import socket

KEEPALIVE_IDLE = 60
KEEPALIVE_INTERVAL = 10
KEEPALIVE_COUNT = 9


def enable_keepalive(sock: socket.socket) -> None:
    """Turn on TCP keepalive with rospy's timing; a no-op for non-TCP sockets (Unix sockets in tests)."""
    if sock.family not in (socket.AF_INET, socket.AF_INET6):
        return
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (
        ("TCP_KEEPIDLE", KEEPALIVE_IDLE),
        ("TCP_KEEPINTVL", KEEPALIVE_INTERVAL),
        ("TCP_KEEPCNT", KEEPALIVE_COUNT),
    ):
        option = getattr(socket, name, None)
        if option is not None:
            sock.setsockopt(socket.IPPROTO_TCP, option, value)
